!> Small dense factorizations for the estimators' element and patch systems (a few to a few
!> dozen unknowns, solved millions of times). LU with partial pivoting for the indefinite
!> element saddle-point systems, Cholesky for the symmetric positive definite patch systems.
!> Plain loops: at these sizes a library call costs more than it saves, and the routines are
!> pure so that each OpenMP thread works on its own automatic arrays.
module twomem_linalg_dense
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: lu_factor, lu_solve, cholesky_factor, cholesky_solve

contains

   !> In place: a = P⁻¹ L U. ok is .false. when a pivot vanishes (the matrix is singular).
   pure subroutine lu_factor(a, piv, ok)
      real(dp), intent(inout) :: a(:, :)
      integer, intent(out) :: piv(:)
      logical, intent(out) :: ok

      integer :: n, j, k, p
      real(dp) :: tmp

      n = size(a, 1)
      ok = .true.
      do k = 1, n
         p = k - 1 + maxloc(abs(a(k:n, k)), dim=1)
         piv(k) = p
         if (a(p, k) == 0.0_dp) then
            ok = .false.
            return
         end if
         if (p /= k) then
            do j = 1, n
               tmp = a(k, j)
               a(k, j) = a(p, j)
               a(p, j) = tmp
            end do
         end if
         a(k + 1:n, k) = a(k + 1:n, k)/a(k, k)
         do j = k + 1, n
            a(k + 1:n, j) = a(k + 1:n, j) - a(k + 1:n, k)*a(k, j)
         end do
      end do
   end subroutine lu_factor

   !> Solve with the factors of `lu_factor`, for every column of b.
   pure subroutine lu_solve(a, piv, b)
      real(dp), intent(in) :: a(:, :)
      integer, intent(in) :: piv(:)
      real(dp), intent(inout) :: b(:, :)

      integer :: n, k, i, j
      real(dp) :: tmp

      n = size(a, 1)
      do j = 1, size(b, 2)
         do k = 1, n
            if (piv(k) /= k) then
               tmp = b(k, j)
               b(k, j) = b(piv(k), j)
               b(piv(k), j) = tmp
            end if
         end do
         do k = 1, n
            do i = k + 1, n
               b(i, j) = b(i, j) - a(i, k)*b(k, j)
            end do
         end do
         do k = n, 1, -1
            b(k, j) = b(k, j)/a(k, k)
            do i = 1, k - 1
               b(i, j) = b(i, j) - a(i, k)*b(k, j)
            end do
         end do
      end do
   end subroutine lu_solve

   !> In place, lower triangle: a = L Lᵀ. ok is .false. if a is not positive definite.
   pure subroutine cholesky_factor(a, ok)
      real(dp), intent(inout) :: a(:, :)
      logical, intent(out) :: ok

      integer :: n, j, k

      n = size(a, 1)
      ok = .true.
      do j = 1, n
         do k = 1, j - 1
            a(j:n, j) = a(j:n, j) - a(j:n, k)*a(j, k)
         end do
         if (.not. a(j, j) > 0.0_dp) then
            ok = .false.
            return
         end if
         a(j:n, j) = a(j:n, j)/sqrt(a(j, j))
      end do
   end subroutine cholesky_factor

   pure subroutine cholesky_solve(a, b)
      real(dp), intent(in) :: a(:, :)
      real(dp), intent(inout) :: b(:, :)

      integer :: n, k, j

      n = size(a, 1)
      do j = 1, size(b, 2)
         do k = 1, n
            b(k, j) = b(k, j)/a(k, k)
            b(k + 1:n, j) = b(k + 1:n, j) - a(k + 1:n, k)*b(k, j)
         end do
         do k = n, 1, -1
            b(k, j) = (b(k, j) - dot_product(a(k + 1:n, k), b(k + 1:n, j)))/a(k, k)
         end do
      end do
   end subroutine cholesky_solve
end module twomem_linalg_dense
