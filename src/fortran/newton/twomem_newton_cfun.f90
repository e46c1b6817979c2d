!> The complementarity functions C(a, b) with a = u1(a) − u2(a), b = λ(a), and the element of
!> their (Clarke) generalized Jacobian that Newton uses, as the pair (∂C/∂a, ∂C/∂b) per vertex.
!> Newton-min takes the a-row where a ≤ b (ties go to the a-row, which enforces contact): it is
!> then a primal–dual active set method.
module twomem_newton_cfun
   use twomem_base_kinds, only: dp, ip
   implicit none
   private

   public :: cfun_min, cfun_eval


   interface cfun_eval
      module procedure cfun_eval_all
   end interface cfun_eval

contains

   pure elemental subroutine cfun_min(a, b, c, da, db)
      real(dp), intent(in) :: a, b
      real(dp), intent(out) :: c, da, db

      if (a <= b) then
         c = a
         da = 1.0_dp
         db = 0.0_dp
      else
         c = b
         da = 0.0_dp
         db = 1.0_dp
      end if
   end subroutine cfun_min

   !> C and its Jacobian entries at every vertex for the C-function `name`.
   subroutine cfun_eval_all(name, a, b, c, da, db)
      character(len=*), intent(in) :: name
      real(dp), intent(in) :: a(:), b(:)
      real(dp), intent(out) :: c(:), da(:), db(:)

      integer(ip) :: i

      select case (name)
      case default
         !$omp parallel do default(none) shared(a, b, c, da, db) private(i) schedule(static)
         do i = 1, size(a, kind=ip)
            call cfun_min(a(i), b(i), c(i), da(i), db(i))
         end do
         !$omp end parallel do
      end select
   end subroutine cfun_eval_all
end module twomem_newton_cfun
