!> The multigrid smoother: Chebyshev iteration preconditioned by the diagonal (Adams, Brezina,
!> Hu & Tuminaro, J. Comput. Phys. 188, 2003). It damps the error components whose eigenvalues
!> of D⁻¹A lie in [λ_max/ratio, λ_max], the part of the spectrum a coarser grid cannot
!> represent. Unlike Gauss–Seidel it is built from matrix–vector products and vector updates
!> only, so it threads perfectly, distributes with one interface sum per product, and gives the
!> same bits for any thread count; and it is a fixed polynomial in A, so the V-cycle stays a
!> fixed linear operator, as a GMRES preconditioner must be. λ_max comes from Gershgorin's
!> theorem for D⁻¹A (max_i Σ_j |a_ij|/a_ii): a guaranteed upper bound, tight for Laplacians (it
!> is 2 for an M-matrix with zero row sums), and free of the random start vectors of a power
!> iteration. The matrix of a distributed run holds each rank's part of the shared rows
!> (`twomem_linalg_halo`): the diagonal and the row sums are summed across ranks, the sums of
!> absolute values of the parts bounding those of the whole rows.
module twomem_linalg_chebyshev
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t, cut_entry
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_vectors, only: copy_allocated, threaded_from
   implicit none
   private

   public :: chebyshev_t, level_product

   !> the arrays of `level_product` and `smooth` for an operator that is not cut
   real(dp), parameter, public :: uncut_diagonal(0) = [real(dp) ::]
   logical, parameter, public :: uncut_fixed(0) = [logical ::]

   type :: chebyshev_t
      integer :: degree = 2
      !> the smoothed interval is [upper/ratio, upper]
      real(dp) :: ratio = 4.0_dp
      real(dp) :: upper = 2.0_dp
      real(dp), allocatable :: inv_diag(:)
      !> this rank's part of each row's diagonal and sum of absolute values, kept so that a
      !> setup for changed rows reads only those
      real(dp), allocatable :: part_diag(:), part_sum(:)
   contains
      procedure :: setup
      procedure :: copy_from
      procedure :: smooth
   end type chebyshev_t

contains

   !> y = A x with the parts of shared rows summed: the product of a distributed operator. With
   !> `diagonal` and `fixed` of a's size, A is a cut at the fixed unknowns with that diagonal
   !> (csr_t%cut_matvec); with uncut_diagonal and uncut_fixed (empty), `a` itself. So are the
   !> operators of `smooth`, and of `setup` given them. The V-cycle passes the two arrays
   !> always: an absent optional array passed on made gfortran build its descriptor from
   !> undefined bounds (the undefined-behaviour sanitizer's negation overflow).
   subroutine level_product(a, halo, x, y, diagonal, fixed)
      type(csr_t), intent(in) :: a
      type(halo_t), intent(inout) :: halo
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)
      real(dp), intent(in) :: diagonal(:)
      logical, intent(in) :: fixed(:)

      if (size(fixed) > 0) then
         call a%cut_matvec(diagonal, fixed, x, y)
      else
         call a%matvec(x, y)
      end if
      call halo%add(y)
   end subroutine level_product

   !> Diagonal and spectral bound of `a` (rows with a non-positive diagonal are left unscaled:
   !> they do not occur in the SPD operators multigrid smooths, but must not divide by zero).
   !> With `rows`, only those rows of `a` changed since the last setup on the same pattern.
   !> `diagonal` and `fixed`: the operator is `a` cut (see `level_product`). Collective.
   subroutine setup(self, a, halo, degree, ratio, rows, diagonal, fixed)
      class(chebyshev_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(halo_t), intent(inout) :: halo
      integer, intent(in) :: degree
      real(dp), intent(in) :: ratio
      integer(ip), intent(in), optional :: rows(:)
      real(dp), intent(in), optional :: diagonal(:)
      logical, intent(in), optional :: fixed(:)

      real(dp), allocatable :: diag(:), row_sum(:)
      integer(ip) :: i, j
      real(dp) :: bound
      logical :: all_rows

      self%degree = degree
      self%ratio = ratio
      all_rows = .not. present(rows)
      if (allocated(self%part_diag)) then
         if (size(self%part_diag) /= a%n) deallocate (self%part_diag, self%part_sum)
      end if
      if (.not. allocated(self%part_diag)) then
         allocate (self%part_diag(a%n), self%part_sum(a%n))
         all_rows = .true.
      end if
      if (all_rows) then
         !$omp parallel do default(none) shared(a, self, diagonal, fixed) private(i) &
         !$omp schedule(static) if(a%n > threaded_from)
         do i = 1, a%n
            call row_parts(a, i, self%part_diag(i), self%part_sum(i), diagonal, fixed)
         end do
         !$omp end parallel do
      else
         !$omp parallel do default(none) shared(a, self, rows, diagonal, fixed) private(j) schedule(static) &
         !$omp if(size(rows) > threaded_from)
         do j = 1, size(rows, kind=ip)
            call row_parts(a, rows(j), self%part_diag(rows(j)), self%part_sum(rows(j)), diagonal, fixed)
         end do
         !$omp end parallel do
      end if
      call copy_allocated(self%part_diag, diag)
      call copy_allocated(self%part_sum, row_sum)
      call halo%add(diag)
      call halo%add(row_sum)
      if (allocated(self%inv_diag)) then
         if (size(self%inv_diag) /= a%n) deallocate (self%inv_diag)
      end if
      if (.not. allocated(self%inv_diag)) allocate (self%inv_diag(a%n))
      bound = 0.0_dp
      !$omp parallel do default(none) shared(a, self, diag, row_sum) private(i) reduction(max:bound) &
      !$omp schedule(static) if(a%n > threaded_from)
      do i = 1, a%n
         if (diag(i) > 0.0_dp) then
            self%inv_diag(i) = 1/diag(i)
            bound = max(bound, row_sum(i)/diag(i))
         else
            self%inv_diag(i) = 1.0_dp
         end if
      end do
      !$omp end parallel do
      self%upper = max(halo%comm%max(bound), 1.0_dp)
   end subroutine setup

   !> self becomes a copy of source, its arrays written by the threads (`copy_allocated`).
   subroutine copy_from(self, source)
      class(chebyshev_t), intent(inout) :: self
      type(chebyshev_t), intent(in) :: source

      self%degree = source%degree
      self%ratio = source%ratio
      self%upper = source%upper
      if (allocated(self%inv_diag)) deallocate (self%inv_diag)
      if (allocated(self%part_diag)) deallocate (self%part_diag)
      if (allocated(self%part_sum)) deallocate (self%part_sum)
      if (allocated(source%inv_diag)) call copy_allocated(source%inv_diag, self%inv_diag)
      if (allocated(source%part_diag)) call copy_allocated(source%part_diag, self%part_diag)
      if (allocated(source%part_sum)) call copy_allocated(source%part_sum, self%part_sum)
   end subroutine copy_from

   !> Row i's diagonal entry and sum of absolute values (of `a` cut, given `diagonal` and `fixed`).
   pure subroutine row_parts(a, i, diag, row_sum, diagonal, fixed)
      type(csr_t), intent(in) :: a
      integer(ip), intent(in) :: i
      real(dp), intent(out) :: diag, row_sum
      real(dp), intent(in), optional :: diagonal(:)
      logical, intent(in), optional :: fixed(:)

      integer(ip) :: k
      real(dp) :: v

      diag = 0.0_dp
      row_sum = 0.0_dp
      do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
         if (present(diagonal)) then
            v = cut_entry(a, diagonal, fixed, i, k)
         else
            v = a%val(k)
         end if
         if (a%col(k) == i) diag = v
         row_sum = row_sum + abs(v)
      end do
   end subroutine row_parts

   !> `degree` Chebyshev steps on A x = b from x (from zero when `from_zero`, saving a product).
   !> r, d and y are work vectors of the size of b. `diagonal` and `fixed`: A is `a` cut, or `a`
   !> itself (uncut_*; see `level_product`).
   subroutine smooth(self, a, halo, b, x, from_zero, r, d, y, diagonal, fixed)
      class(chebyshev_t), intent(in) :: self
      type(csr_t), intent(in) :: a
      type(halo_t), intent(inout) :: halo
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      logical, intent(in) :: from_zero
      real(dp), intent(inout) :: r(:), d(:), y(:)
      real(dp), intent(in) :: diagonal(:)
      logical, intent(in) :: fixed(:)

      real(dp) :: theta, delta, sigma, rho, rho_old
      integer(ip) :: i, n
      integer :: k

      n = a%n
      theta = 0.5_dp*(self%upper + self%upper/self%ratio)
      delta = 0.5_dp*(self%upper - self%upper/self%ratio)
      sigma = theta/delta
      rho_old = 1/sigma
      if (from_zero) then
         !$omp parallel do default(none) shared(n, b, x, d, r, self, theta) private(i) &
         !$omp schedule(static) if(n > threaded_from)
         do i = 1, n
            d(i) = self%inv_diag(i)*b(i)/theta
            x(i) = d(i)
            r(i) = b(i)
         end do
         !$omp end parallel do
      else
         call level_product(a, halo, x, y, diagonal, fixed)
         !$omp parallel do default(none) shared(n, b, x, d, r, y, self, theta) private(i) &
         !$omp schedule(static) if(n > threaded_from)
         do i = 1, n
            r(i) = b(i) - y(i)
            d(i) = self%inv_diag(i)*r(i)/theta
            x(i) = x(i) + d(i)
         end do
         !$omp end parallel do
      end if
      do k = 2, self%degree
         ! r ← r − A d, then the three-term recurrence for the next correction
         call level_product(a, halo, d, y, diagonal, fixed)
         rho = 1/(2*sigma - rho_old)
         !$omp parallel do default(none) shared(n, x, d, r, y, self, rho, rho_old, delta) private(i) &
         !$omp schedule(static) if(n > threaded_from)
         do i = 1, n
            r(i) = r(i) - y(i)
            d(i) = rho*rho_old*d(i) + 2*rho/delta*self%inv_diag(i)*r(i)
            x(i) = x(i) + d(i)
         end do
         !$omp end parallel do
         rho_old = rho
      end do
   end subroutine smooth
end module twomem_linalg_chebyshev
