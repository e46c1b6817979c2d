!> The multigrid smoother: Chebyshev iteration preconditioned by the diagonal (Adams, Brezina,
!> Hu & Tuminaro, J. Comput. Phys. 188, 2003). It damps the error components whose eigenvalues
!> of D⁻¹A lie in [λ_max/ratio, λ_max], the part of the spectrum a coarser grid cannot
!> represent. Unlike Gauss–Seidel it is built from matrix–vector products and vector updates
!> only, so it threads perfectly and gives the same bits for any thread count; and it is a fixed
!> polynomial in A, so the V-cycle stays a fixed linear operator, as a GMRES preconditioner
!> must be. λ_max comes from Gershgorin's theorem for D⁻¹A (max_i Σ_j |a_ij|/a_ii): a guaranteed
!> upper bound, tight for Laplacians (it is 2 for an M-matrix with zero row sums), and free of
!> the random start vectors of a power iteration.
module twomem_linalg_chebyshev
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t
   implicit none
   private

   public :: chebyshev_t

   type :: chebyshev_t
      integer :: degree = 2
      !> the smoothed interval is [upper/ratio, upper]
      real(dp) :: ratio = 4.0_dp
      real(dp) :: upper = 2.0_dp
      real(dp), allocatable :: inv_diag(:)
   contains
      procedure :: setup
      procedure :: smooth
   end type chebyshev_t

contains

   !> Diagonal and spectral bound of `a` (rows with a non-positive diagonal are left unscaled:
   !> they do not occur in the SPD operators multigrid smooths, but must not divide by zero).
   subroutine setup(self, a, degree, ratio)
      class(chebyshev_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      integer, intent(in) :: degree
      real(dp), intent(in) :: ratio

      integer(ip) :: i, k
      real(dp) :: diag, row_sum, bound

      self%degree = degree
      self%ratio = ratio
      if (allocated(self%inv_diag)) then
         if (size(self%inv_diag) /= a%n) deallocate (self%inv_diag)
      end if
      if (.not. allocated(self%inv_diag)) allocate (self%inv_diag(a%n))
      bound = 0.0_dp
      !$omp parallel do default(none) shared(a, self) private(i, k, diag, row_sum) reduction(max:bound) &
      !$omp schedule(static) if(a%n > 4096)
      do i = 1, a%n
         diag = 0.0_dp
         row_sum = 0.0_dp
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (a%col(k) == i) diag = a%val(k)
            row_sum = row_sum + abs(a%val(k))
         end do
         if (diag > 0.0_dp) then
            self%inv_diag(i) = 1/diag
            bound = max(bound, row_sum/diag)
         else
            self%inv_diag(i) = 1.0_dp
         end if
      end do
      !$omp end parallel do
      self%upper = max(bound, 1.0_dp)
   end subroutine setup

   !> `degree` Chebyshev steps on A x = b from x (from zero when `from_zero`, saving a product).
   !> r and d are work vectors of the size of b.
   subroutine smooth(self, a, b, x, from_zero, r, d)
      class(chebyshev_t), intent(in) :: self
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      logical, intent(in) :: from_zero
      real(dp), intent(inout) :: r(:), d(:)

      real(dp) :: theta, delta, sigma, rho, rho_old
      integer(ip) :: i, n
      integer :: k

      n = a%n
      theta = 0.5_dp*(self%upper + self%upper/self%ratio)
      delta = 0.5_dp*(self%upper - self%upper/self%ratio)
      sigma = theta/delta
      rho_old = 1/sigma
      if (from_zero) then
         !$omp parallel do default(none) shared(n, b, x, d, r, self, theta) private(i) schedule(static) if(n > 4096)
         do i = 1, n
            d(i) = self%inv_diag(i)*b(i)/theta
            x(i) = d(i)
            r(i) = b(i)
         end do
         !$omp end parallel do
      else
         call a%residual(b, x, r)
         !$omp parallel do default(none) shared(n, x, d, r, self, theta) private(i) schedule(static) if(n > 4096)
         do i = 1, n
            d(i) = self%inv_diag(i)*r(i)/theta
            x(i) = x(i) + d(i)
         end do
         !$omp end parallel do
      end if
      do k = 2, self%degree
         ! r ← r − A d, then the three-term recurrence for the next correction
         call a%subtract_product(d, r)
         rho = 1/(2*sigma - rho_old)
         !$omp parallel do default(none) shared(n, x, d, r, self, rho, rho_old, delta) private(i) &
         !$omp schedule(static) if(n > 4096)
         do i = 1, n
            d(i) = rho*rho_old*d(i) + 2*rho/delta*self%inv_diag(i)*r(i)
            x(i) = x(i) + d(i)
         end do
         !$omp end parallel do
         rho_old = rho
      end do
   end subroutine smooth
end module twomem_linalg_chebyshev
