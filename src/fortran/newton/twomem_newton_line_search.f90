!> Backtracking on the merit ‖[D⁻¹(F − E X); C(X)]‖ (see `twomem_newton_residual`): halve the
!> step until the merit falls below the largest of its last five values (Armijo, σ = 1e-4, with
!> the non-monotone reference of Grippo, Lampariello and Lucidi, SINUM 1986). Semismooth
!> Newton's residual may rise for a step or two on its way, and a monotone rule then forces tiny
!> steps (measured: Fischer–Burmeister took 33 steps instead of 10, or failed). A step that never
!> satisfies the test is taken in full, so Newton-min keeps its finite active-set termination.
module twomem_newton_line_search
   use twomem_base_kinds, only: dp
   use twomem_newton_residual, only: nonlinear_residual_t
   implicit none
   private

   public :: line_search_t

   type :: line_search_t
      !> merits of the last iterates, a ring indexed by the Newton step
      real(dp) :: recent(5) = 0.0_dp
      !> a backtracking trial (allocated by the first step that backtracks)
      real(dp), allocatable :: trial(:)
   contains
      procedure :: step
   end type line_search_t

contains

   !> The step α ∈ (0, 1] from x towards x_new at Newton step k, given the merits of both (the
   !> driver has them from its residual evaluations: a full step, the common case, costs no
   !> evaluation here).
   real(dp) function step(self, residual, k, x, merit_x, x_new, merit_new) result(alpha)
      class(line_search_t), intent(inout) :: self
      type(nonlinear_residual_t), intent(inout) :: residual
      integer, intent(in) :: k
      real(dp), intent(in) :: x(:), merit_x, x_new(:), merit_new

      real(dp) :: reference, merit
      integer :: halvings

      self%recent(modulo(k - 1, size(self%recent)) + 1) = merit_x
      reference = maxval(self%recent)
      alpha = 1.0_dp
      merit = merit_new
      do halvings = 0, 30
         if (halvings > 0) then
            alpha = alpha/2
            if (.not. allocated(self%trial)) allocate (self%trial(size(x)))
            self%trial = x + alpha*(x_new - x)
            merit = residual%merit(self%trial)
         end if
         if (merit <= (1 - 1.0e-4_dp*alpha)*reference) return
      end do
      alpha = 1.0_dp
   end function step
end module twomem_newton_line_search
