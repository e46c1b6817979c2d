!> The complementarity functions C(a, b) with a = u1(a) − u2(a), b = λ(a), and the element of
!> their (Clarke) generalized Jacobian that Newton uses, as the pair (∂C/∂a, ∂C/∂b) per vertex.
!>
!> - `min`: C = min(a, b). Newton takes the a-row where a ≤ b (ties go to the a-row, which
!>   imposes contact), so Newton-min is a primal–dual active set method.
!> - `fb` (Fischer–Burmeister): C = sqrt(a² + b²) − a − b, smooth except at a = b = 0. Away
!>   from the kink ∂C/∂a = a/ρ − 1, ∂C/∂b = b/ρ − 1 with ρ = sqrt(a² + b²). At the kink the
!>   Clarke Jacobian is {(ξ − 1, η − 1): ξ² + η² ≤ 1}; we take ξ = η = 1/√2, the limit along
!>   the diagonal a = b > 0, whose row weighs both conditions equally and stays nonsingular.
!>   ρ is computed with `hypot`, so no overflow or underflow for extreme a, b.
module twomem_newton_cfun
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: c_function_fb
   use twomem_linalg_vectors, only: threaded_from
   implicit none
   private

   public :: cfun_min, cfun_fb, cfun_eval

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

   pure elemental subroutine cfun_fb(a, b, c, da, db)
      real(dp), intent(in) :: a, b
      real(dp), intent(out) :: c, da, db

      real(dp), parameter :: kink = 1.0_dp/sqrt(2.0_dp)
      real(dp) :: rho

      rho = hypot(a, b)
      if (rho > 0.0_dp) then
         ! sqrt(a²+b²) − a − b loses all digits when a, b > 0 and one dominates; the product
         ! form −2ab/(ρ + a + b) is exact there
         if (a > 0.0_dp .and. b > 0.0_dp) then
            c = -2*a*b/(rho + a + b)
         else
            c = rho - a - b
         end if
         da = a/rho - 1
         db = b/rho - 1
      else
         c = 0.0_dp
         da = kink - 1
         db = kink - 1
      end if
   end subroutine cfun_fb

   !> C and its Jacobian entries at every vertex for C-function `which` (c_function_min or
   !> c_function_fb) at the iterate x = [X1; X2; X3]: a = X1 − X2, b = X3.
   subroutine cfun_eval(which, x, c, da, db)
      integer, intent(in) :: which
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: c(:), da(:), db(:)

      integer(ip) :: i, n

      n = size(c, kind=ip)
      if (which == c_function_fb) then
         !$omp parallel do default(none) shared(x, c, da, db, n) private(i) schedule(static) if(n > threaded_from)
         do i = 1, n
            call cfun_fb(x(i) - x(n + i), x(2*n + i), c(i), da(i), db(i))
         end do
         !$omp end parallel do
      else
         !$omp parallel do default(none) shared(x, c, da, db, n) private(i) schedule(static) if(n > threaded_from)
         do i = 1, n
            call cfun_min(x(i) - x(n + i), x(2*n + i), c(i), da(i), db(i))
         end do
         !$omp end parallel do
      end if
   end subroutine cfun_eval
end module twomem_newton_cfun
