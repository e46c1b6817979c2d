!> The verification cases of docs/method.md §4, both on the unit disk with closed-form solutions:
!> `bbbv`, the paper's case (its data are fixed: μ1 = μ2 = 1, g = 0.05, loads that jump at
!> r0 = 1/√2), and `radial`, constant data with a contact disk of radius ρ found from a scalar
!> equation. `make_problem` turns the plain input values into the right data object.
module twomem_fem_cases
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_base_options, only: exact_none, exact_radial, exact_bbbv
   use twomem_fem_problem, only: problem_data_t, constant_data_t
   implicit none
   private

   public :: bbbv_data_t, radial_data_t, make_problem

   type, extends(problem_data_t) :: bbbv_data_t
      real(dp) :: r0 = 0.0_dp, c = 0.0_dp
   contains
      procedure :: load => bbbv_load
      procedure :: has_exact => always_exact
      procedure :: exact => bbbv_exact
   end type bbbv_data_t

   type, extends(constant_data_t) :: radial_data_t
      !> D = f2/μ2 − f1/μ1 and the contact radius ρ (0 without contact)
      real(dp) :: d = 0.0_dp, rho = 0.0_dp
      logical :: contact = .false.
   contains
      procedure :: has_exact => always_exact_radial
      procedure :: exact => radial_exact
      procedure :: exact_gradients_at => radial_gradients_at
   end type radial_data_t

contains

   !> Build the data of a case: `exact` is exact_none, exact_radial or exact_bbbv (bbbv ignores
   !> the values).
   subroutine make_problem(exact, mu1, mu2, f1, f2, g, problem, err)
      integer, intent(in) :: exact
      real(dp), intent(in) :: mu1, mu2, f1, f2, g
      class(problem_data_t), allocatable, intent(out) :: problem
      type(error_t), allocatable, intent(out) :: err

      select case (exact)
      case (exact_none)
         allocate (problem, source=constant_data_t(mu1=mu1, mu2=mu2, g=g, name='constant', f1=f1, f2=f2))
      case (exact_bbbv)
         problem = new_bbbv()
      case (exact_radial)
         problem = new_radial(mu1, mu2, f1, f2, g)
      case default
         call make_error(err, exit_bad_input, 'problem.exact', 'unknown case')
      end select
   end subroutine make_problem

   function new_bbbv() result(p)
      type(bbbv_data_t) :: p

      p%name = 'bbbv'
      p%mu1 = 1.0_dp
      p%mu2 = 1.0_dp
      p%g = 0.05_dp
      p%r0 = 1.0_dp/sqrt(2.0_dp)
      p%c = p%g*sqrt(2.0_dp)/(sqrt(2.0_dp) - 1.0_dp)
   end function new_bbbv

   function new_radial(mu1, mu2, f1, f2, g) result(p)
      real(dp), intent(in) :: mu1, mu2, f1, f2, g
      type(radial_data_t) :: p

      real(dp) :: lo, hi, mid, target
      integer :: it

      p%name = 'radial'
      p%mu1 = mu1
      p%mu2 = mu2
      p%f1 = f1
      p%f2 = f2
      p%g = g
      p%d = f2/mu2 - f1/mu1
      p%contact = p%d > 4*g
      if (.not. p%contact) return
      ! (D/4)(1 − ρ² + 2ρ² ln ρ) = g: the left side falls monotonically from D/4 at ρ = 0 to 0 at
      ! ρ = 1, so bisection converges to the unique root.
      target = 4*g/p%d
      lo = 0.0_dp
      hi = 1.0_dp
      do it = 1, 200
         mid = 0.5_dp*(lo + hi)
         if (contact_profile(mid) > target) then
            lo = mid
         else
            hi = mid
         end if
         if (hi - lo <= 4*epsilon(1.0_dp)) exit
      end do
      p%rho = 0.5_dp*(lo + hi)
   end function new_radial

   pure real(dp) function contact_profile(rho)
      real(dp), intent(in) :: rho

      if (rho <= 0.0_dp) then
         contact_profile = 1.0_dp
      else
         contact_profile = 1.0_dp - rho**2 + 2*rho**2*log(rho)
      end if
   end function contact_profile

   pure logical function always_exact(self)
      class(bbbv_data_t), intent(in) :: self

      always_exact = .true.
   end function always_exact

   pure logical function always_exact_radial(self)
      class(radial_data_t), intent(in) :: self

      always_exact_radial = .true.
   end function always_exact_radial

   pure real(dp) function bbbv_load(self, alpha, x)
      class(bbbv_data_t), intent(in) :: self
      integer, intent(in) :: alpha
      real(dp), intent(in) :: x(2)

      real(dp) :: r

      r = norm2(x)
      if (alpha == 1) then
         bbbv_load = merge(-10*self%g, -8*self%g, r <= self%r0)
      else if (r <= self%r0) then
         bbbv_load = -6*self%g
      else
         bbbv_load = -self%c*(1 + 8*r - 18*r**2)/r
      end if
   end function bbbv_load

   pure subroutine bbbv_exact(self, x, u, grad)
      class(bbbv_data_t), intent(in) :: self
      real(dp), intent(in) :: x(2)
      real(dp), intent(out) :: u(3)
      real(dp), intent(out) :: grad(2, 2)

      real(dp) :: r, du2

      r = norm2(x)
      u(1) = self%g*(2*r**2 - 1)
      ! d/dr of a radial function times x/r: for u1 = g(2r² − 1), ∇u1 = 4g x
      grad(:, 1) = 4*self%g*x
      if (r <= self%r0) then
         u(2) = u(1)
         u(3) = 2*self%g
         grad(:, 2) = grad(:, 1)
      else
         u(2) = self%c*(1 - r)*(2*r**2 - 1)
         u(3) = 0.0_dp
         du2 = self%c*(4*r - 6*r**2 + 1)
         grad(:, 2) = du2*x/r
      end if
   end subroutine bbbv_exact

   pure subroutine radial_exact(self, x, u, grad)
      class(radial_data_t), intent(in) :: self
      real(dp), intent(in) :: x(2)
      real(dp), intent(out) :: u(3)
      real(dp), intent(out) :: grad(2, 2)

      real(dp) :: r, w, s, msum

      r = norm2(x)
      msum = self%mu1 + self%mu2
      s = self%mu1*self%g + (self%f1 + self%f2)*(1 - r**2)/4
      if (.not. self%contact) then
         w = self%g + self%d*(r**2 - 1)/4
      else if (r <= self%rho) then
         w = 0.0_dp
      else
         w = (self%d/4)*(r**2 - self%rho**2) - (self%d*self%rho**2/2)*log(r/self%rho)
      end if
      u(1) = (s + self%mu2*w)/msum
      u(2) = (s - self%mu1*w)/msum
      u(3) = 0.0_dp
      if (self%contact .and. r <= self%rho) u(3) = (self%mu1*self%f2 - self%mu2*self%f1)/msum
      grad = radial_gradient(self, x)
   end subroutine radial_exact

   !> The energy error's integration points need the gradients alone: no logarithm.
   pure subroutine radial_gradients_at(self, x, grad)
      class(radial_data_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: grad(:, :, :)

      integer :: k

      do k = 1, size(x, 2)
         grad(:, :, k) = radial_gradient(self, x(:, k))
      end do
   end subroutine radial_gradients_at

   !> [∇u1, ∇u2] at x, from S = μ1 u1 + μ2 u2 and w = u1 − u2 (both radial): ∇v = (v'(r)/r) x,
   !> with v'/r finite at the centre. Only r² is needed: no square root (the energy error
   !> evaluates this at every quadrature point of every triangle, where norm2's scaled sum was
   !> a large part of the error's time).
   pure function radial_gradient(self, x) result(grad)
      class(radial_data_t), intent(in) :: self
      real(dp), intent(in) :: x(2)
      real(dp) :: grad(2, 2)

      real(dp) :: r_squared, dw_over_r, ds_over_r, msum

      r_squared = x(1)**2 + x(2)**2
      msum = self%mu1 + self%mu2
      ds_over_r = -(self%f1 + self%f2)/2
      if (.not. self%contact) then
         dw_over_r = self%d/2
      else if (r_squared <= self%rho**2) then
         dw_over_r = 0.0_dp
      else
         dw_over_r = self%d/2 - self%d*self%rho**2/(2*r_squared)
      end if
      grad(:, 1) = (ds_over_r + self%mu2*dw_over_r)/msum*x
      grad(:, 2) = (ds_over_r - self%mu1*dw_over_r)/msum*x
   end function radial_gradient
end module twomem_fem_cases
