!> The small dense factorizations of the estimators' element and patch systems: LU with partial
!> pivoting, Cholesky, and their detection of singular (or indefinite) matrices.
module test_dense
   use twomem_base_kinds, only: dp
   use twomem_linalg_dense, only: lu_factor, lu_solve, cholesky_factor, cholesky_solve
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   implicit none
   private

   public :: collect_dense

contains

   subroutine collect_dense(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('lu_solve_residual', test_lu), &
               new_unittest('cholesky_factor_and_solve', test_cholesky), &
               new_unittest('singular_detected', test_singular)]
   end subroutine collect_dense

   !> A random nonsymmetric 7×7 with a zero leading entry (so pivoting is needed) and three
   !> right-hand sides at once: backward-stable residuals.
   subroutine test_lu(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp) :: a(7, 7), lu(7, 7), b(7, 3), x(7, 3)
      integer :: piv(7), j
      logical :: ok

      call seeded_random(a, 5)
      call seeded_random(b, 6)
      a(1, 1) = 0.0_dp
      lu = a
      call lu_factor(lu, piv, ok)
      call check(err, ok, 'regular matrix factorized')
      call check(err, piv(1) /= 1, 'zero leading entry pivoted away')
      x = b
      call lu_solve(lu, piv, x)
      do j = 1, 3
         call check(err, norm2(matmul(a, x(:, j)) - b(:, j)) <= 1.0e-13_dp*maxval(abs(a))*norm2(x(:, j)), &
                    'residual of A x = b')
      end do
   end subroutine test_lu

   !> A = BᵀB + I: L Lᵀ (lower triangle) reproduces A, and the solve has a small residual.
   subroutine test_cholesky(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp) :: a(6, 6), f(6, 6), l(6, 6), b(6, 2), x(6, 2)
      integer :: i
      logical :: ok

      call seeded_random(f, 7)
      a = matmul(transpose(f), f)
      do i = 1, 6
         a(i, i) = a(i, i) + 1
      end do
      l = a
      call cholesky_factor(l, ok)
      call check(err, ok, 'SPD matrix factorized')
      do i = 1, 6
         l(1:i - 1, i) = 0.0_dp
      end do
      call check(err, maxval(abs(matmul(l, transpose(l)) - a)) <= 1.0e-14_dp*maxval(abs(a)), 'L L^T = A')
      call seeded_random(b, 8)
      x = b
      call cholesky_factor(a, ok)
      call cholesky_solve(a, x)
      a = matmul(transpose(f), f)
      do i = 1, 6
         a(i, i) = a(i, i) + 1
      end do
      call check(err, maxval(abs(matmul(a, x) - b)) <= 1.0e-13_dp*maxval(abs(a))*maxval(abs(x)), 'residual of A x = b')
   end subroutine test_cholesky

   !> Exactly rank-deficient matrices (elimination is exact on these small integers): LU reports
   !> a zero pivot; Cholesky rejects a semidefinite and an indefinite matrix.
   subroutine test_singular(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp) :: a(3, 3), s(2, 2)
      integer :: piv(3)
      logical :: ok

      a = reshape([1.0_dp, 2.0_dp, 1.0_dp, 2.0_dp, 4.0_dp, 1.0_dp, 3.0_dp, 6.0_dp, 1.0_dp], [3, 3])
      call lu_factor(a, piv, ok)
      call check(err, .not. ok, 'rank-2 matrix singular for LU')
      a = reshape([1.0_dp, 2.0_dp, 3.0_dp, 0.0_dp, 0.0_dp, 0.0_dp, 4.0_dp, 5.0_dp, 6.0_dp], [3, 3])
      call lu_factor(a, piv, ok)
      call check(err, .not. ok, 'zero column singular for LU')
      s = reshape([1.0_dp, 1.0_dp, 1.0_dp, 1.0_dp], [2, 2])
      call cholesky_factor(s, ok)
      call check(err, .not. ok, 'semidefinite rejected by Cholesky')
      s = reshape([1.0_dp, 2.0_dp, 2.0_dp, 1.0_dp], [2, 2])
      call cholesky_factor(s, ok)
      call check(err, .not. ok, 'indefinite rejected by Cholesky')
   end subroutine test_singular

   !> Uniform values in [−1/2, 1/2), reproducible from `seed`.
   subroutine seeded_random(a, seed)
      real(dp), intent(out) :: a(:, :)
      integer, intent(in) :: seed

      integer, allocatable :: state(:)
      integer :: k, i

      call random_seed(size=k)
      state = [(seed*7919 + 104729*i, i=1, k)]
      call random_seed(put=state)
      call random_number(a)
      a = a - 0.5_dp
   end subroutine seeded_random
end module test_dense
