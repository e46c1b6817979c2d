!> The nonlinear residual of the discrete problem at an iterate X: the membrane rows F − E X and
!> the C-function C(X), with the two norms Newton uses. The paper's stopping test measures
!> ‖[F − E X; −C(X)]‖/‖[F; 0]‖ (the relative linearization residual); the line search measures
!> the membrane rows as strong residuals D⁻¹(F − E X), in load units and independent of h, so
!> that they weigh like the C-function rows. Both are evaluated into work vectors held here:
!> they are called every Newton step, every ν GMRES iterations and at every backtracking trial.
!> Both are global: sums over every rank's owned unknowns. With `track_merit` (the line search
!> is on), `relative` also leaves the merit of its iterate in `last_merit`: one weighted sum
!> more, where a separate `merit` would cost another C-function and E X, and the driver knows
!> the merits of its iterate and of GMRES's from the evaluations it makes anyway.
module twomem_newton_residual
   use twomem_base_kinds, only: dp, ip
   use twomem_newton_cfun, only: cfun_eval
   use twomem_newton_system, only: newton_system_t
   implicit none
   private

   public :: nonlinear_residual_t

   type :: nonlinear_residual_t
      type(newton_system_t), pointer :: sys => null()
      !> c_function_min or c_function_fb
      integer :: cfun = 0
      !> ‖[F; 0]‖ (1 if F vanishes)
      real(dp) :: f_norm = 1.0_dp
      !> 1/(|ω_a|/3) per vertex, for the merit (allocated only with the line search: Newton-min
      !> runs without)
      real(dp), allocatable :: inv_mass(:)
      !> `relative` computes the merit too, into `last_merit`
      logical :: track_merit = .false.
      real(dp) :: last_merit = 0.0_dp
      !> work: E X, and C with its Jacobian for `merit` (allocated at its first call: only a
      !> backtracking trial needs them)
      real(dp), allocatable :: ex(:), c(:), da(:), db(:)
   contains
      procedure :: init
      procedure :: relative
      procedure :: merit
   end type nonlinear_residual_t

contains

   subroutine init(self, sys, cfun, track_merit)
      class(nonlinear_residual_t), intent(out) :: self
      type(newton_system_t), target, intent(in) :: sys
      integer, intent(in) :: cfun
      logical, intent(in) :: track_merit

      self%sys => sys
      self%cfun = cfun
      self%f_norm = sqrt(sys%sum_squares(sys%f))
      if (.not. self%f_norm > 0.0_dp) self%f_norm = 1.0_dp
      allocate (self%ex(2*sys%n))
      self%track_merit = track_merit
      if (track_merit) self%inv_mass = 1/sys%mass
   end subroutine init

   !> ‖[F − E X; −C(X)]‖/‖[F; 0]‖, with C and its Jacobian at x (and `last_merit`, tracked).
   subroutine relative(self, x, rel, c, da, db)
      class(nonlinear_residual_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: rel
      real(dp), intent(out) :: c(:), da(:), db(:)

      real(dp) :: c_squares

      call cfun_eval(self%cfun, x, c, da, db)
      call self%sys%apply_e(x, self%ex)
      c_squares = self%sys%sum_squares(c)
      rel = sqrt(self%sys%sum_squares(self%sys%f, minus=self%ex) + c_squares)/self%f_norm
      ! the same sums as `merit` makes at x: the same bits
      if (self%track_merit) &
         self%last_merit = sqrt(self%sys%sum_squares(self%sys%f, minus=self%ex, weight=self%inv_mass) + c_squares)
   end subroutine relative

   !> ‖[D⁻¹(F − E X); C(X)]‖. With the weak rows instead, (g, 0, 0) looks almost solved
   !> (C(g, 0) = 0 and F ~ h²) and every useful first step looks like a huge increase.
   real(dp) function merit(self, x)
      class(nonlinear_residual_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)

      if (.not. allocated(self%c)) allocate (self%c(self%sys%n), self%da(self%sys%n), self%db(self%sys%n))
      if (.not. allocated(self%inv_mass)) self%inv_mass = 1/self%sys%mass
      call cfun_eval(self%cfun, x, self%c, self%da, self%db)
      call self%sys%apply_e(x, self%ex)
      merit = sqrt(self%sys%sum_squares(self%sys%f, minus=self%ex, weight=self%inv_mass) + self%sys%sum_squares(self%c))
   end function merit
end module twomem_newton_residual
