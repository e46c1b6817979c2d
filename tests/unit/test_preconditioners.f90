!> ILU(0) and Jacobi preconditioners: ILU(0) is the exact LU where no fill exists, matches a
!> dense ILU(0) restricted to the pattern elsewhere, refactorizes on a kept pattern, fills the
!> zero λ-λ diagonal of the Newton matrix in block order as predicted, and reports breakdowns
!> as errors naming the row, and in an order set by keys factorizes the permuted matrix; Jacobi
!> inverts diagonals and leaves zero-diagonal rows unscaled.
module test_preconditioners
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: exit_not_converged
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_ilu0, only: ilu0_preconditioner_t
   use twomem_linalg_jacobi, only: jacobi_preconditioner_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_system, only: newton_system_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_refinement, only: square_problem
   implicit none
   private

   public :: collect_preconditioners

   real(dp), parameter :: eps = epsilon(1.0_dp)

contains

   subroutine collect_preconditioners(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('ilu0_tridiagonal_is_exact_lu', test_tridiagonal), &
               new_unittest('ilu0_laplacian_matches_dense_ilu0', test_laplacian), &
               new_unittest('ilu0_refactor_on_kept_pattern', test_refactor), &
               new_unittest('ilu0_in_key_order_is_ilu0_of_permuted', test_key_order), &
               new_unittest('ilu0_newton_zero_diagonal', test_newton_matrix), &
               new_unittest('ilu0_breakdown_names_row', test_breakdown), &
               new_unittest('jacobi_diagonal_inverse', test_jacobi), &
               new_unittest('jacobi_newton_active_rows', test_jacobi_newton)]
   end subroutine collect_preconditioners

   !> CSR with the pattern `mask` (diagonal always included) and the values of `d` on it.
   subroutine csr_from_dense(d, mask, a, with_diagonal)
      real(dp), intent(in) :: d(:, :)
      logical, intent(in) :: mask(:, :)
      type(csr_t), intent(out) :: a
      logical, intent(in), optional :: with_diagonal

      integer(ip) :: n, i, j, k
      integer(ip), allocatable :: row_ptr(:), col(:)
      logical :: diag

      diag = .true.
      if (present(with_diagonal)) diag = with_diagonal
      n = int(size(d, 1), ip)
      allocate (row_ptr(n + 1), col(n*n))
      row_ptr(1) = 1
      k = 0
      do i = 1, n
         do j = 1, n
            if (mask(i, j) .or. (diag .and. i == j)) then
               k = k + 1
               col(k) = j
            end if
         end do
         row_ptr(i + 1) = k + 1
      end do
      call a%init_pattern(row_ptr, col(1:k))
      do i = 1, n
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            a%val(k) = d(i, a%col(k))
         end do
      end do
   end subroutine csr_from_dense

   !> Dense ILU(0), IKJ, restricted to `mask`: the independent reference.
   function dense_ilu0(d, mask) result(w)
      real(dp), intent(in) :: d(:, :)
      logical, intent(in) :: mask(:, :)
      real(dp) :: w(size(d, 1), size(d, 2))

      integer :: i, j, k, n

      n = size(d, 1)
      w = d
      do i = 2, n
         do k = 1, i - 1
            if (.not. mask(i, k)) cycle
            w(i, k) = w(i, k)/w(k, k)
            do j = k + 1, n
               if (mask(i, j)) w(i, j) = w(i, j) - w(i, k)*w(k, j)
            end do
         end do
      end do
   end function dense_ilu0

   !> 5-point Laplacian on an m×m grid, lexicographic order, plus `shift` on the diagonal.
   function laplacian(m, shift) result(d)
      integer, intent(in) :: m
      real(dp), intent(in) :: shift
      real(dp) :: d(m*m, m*m)

      integer :: ix, iy, i

      d = 0.0_dp
      do iy = 1, m
         do ix = 1, m
            i = ix + (iy - 1)*m
            d(i, i) = 4.0_dp + shift
            if (ix > 1) d(i, i - 1) = -1.0_dp
            if (ix < m) d(i, i + 1) = -1.0_dp
            if (iy > 1) d(i, i - m) = -1.0_dp
            if (iy < m) d(i, i + m) = -1.0_dp
         end do
      end do
   end function laplacian

   !> Deterministic values in [-1, 1) (Park–Miller), so failures reproduce.
   subroutine fill_random(state, v)
      integer(i8), intent(inout) :: state
      real(dp), intent(out) :: v(:)

      integer :: i

      do i = 1, size(v)
         state = mod(16807_i8*state, 2147483647_i8)
         v(i) = 2.0_dp*real(state, dp)/2147483647.0_dp - 1.0_dp
      end do
   end subroutine fill_random

   !> Largest difference between the ILU(0) factors held by `m` and the dense reference `w`
   !> over the pattern `mask` (diagonal included).
   real(dp) function factor_difference(m, w, mask) result(diff)
      type(ilu0_preconditioner_t), intent(in) :: m
      real(dp), intent(in) :: w(:, :)
      logical, intent(in) :: mask(:, :)

      integer(ip) :: i, j

      diff = 0.0_dp
      do j = 1, int(size(w, 2), ip)
         do i = 1, int(size(w, 1), ip)
            if (mask(i, j) .or. i == j) diff = max(diff, abs(m%factor_entry(i, j) - w(i, j)))
         end do
      end do
   end function factor_difference

   !> Largest |(L U)_ij − a_ij| over the pattern, relative to Σ_k |l_ik u_kj| + |a_ij|.
   real(dp) function lu_matches_pattern(m, a) result(worst)
      type(ilu0_preconditioner_t), intent(in) :: m
      type(csr_t), intent(in) :: a

      integer(ip) :: i, j, k, p, q
      real(dp) :: s, scale, l

      worst = 0.0_dp
      do i = 1, a%n
         do p = a%row_ptr(i), a%row_ptr(i + 1) - 1
            j = a%col(p)
            s = 0.0_dp
            scale = abs(a%val(p))
            do q = a%row_ptr(i), a%row_ptr(i + 1) - 1
               k = a%col(q)
               if (k > min(i, j)) exit
               l = 1.0_dp
               if (k < i) l = m%factor_entry(i, k)
               s = s + l*m%factor_entry(k, j)
               scale = scale + abs(l*m%factor_entry(k, j))
            end do
            if (scale > 0.0_dp) worst = max(worst, abs(s - a%val(p))/scale)
         end do
      end do
   end function lu_matches_pattern

   !> Iterations of x ← x + M⁻¹(b − A x) from x = 0 until the error is below 1e-8 relative,
   !> for a random solution; a large number if it does not get there in 1000.
   integer function richardson_iterations(m, a, state) result(it)
      type(ilu0_preconditioner_t), intent(inout) :: m
      type(csr_t), intent(in) :: a
      integer(i8), intent(inout) :: state

      real(dp), allocatable :: x_true(:), b(:), x(:), r(:), z(:)

      allocate (x_true(a%n), b(a%n), x(a%n), r(a%n), z(a%n))
      call fill_random(state, x_true)
      call a%matvec(x_true, b)
      x = 0.0_dp
      do it = 1, 1000
         call a%matvec(x, r)
         r = b - r
         call m%apply(r, z)
         x = x + z
         if (norm2(x - x_true) <= 1.0e-8_dp*norm2(x_true)) return
      end do
      it = huge(it)
   end function richardson_iterations

   subroutine test_tridiagonal(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: n = 40
      real(dp) :: d(n, n), x(n), y(n), z(n)
      type(csr_t) :: a
      type(ilu0_preconditioner_t) :: m
      integer :: i
      integer(i8) :: state

      ! nonsymmetric, not diagonally dominant everywhere: pivots vary, none vanishes
      d = 0.0_dp
      do i = 1, n
         d(i, i) = 2.0_dp + 0.5_dp*sin(real(i, dp))
      end do
      do i = 2, n
         d(i, i - 1) = -1.3_dp + 0.1_dp*cos(real(i, dp))
         d(i - 1, i) = -0.6_dp
      end do
      call csr_from_dense(d, d /= 0.0_dp, a)
      call m%setup(a, err)
      if (allocated(err)) return
      state = 12345_i8
      call fill_random(state, x)
      call a%matvec(x, y)
      call m%apply(y, z)
      call check(err, maxval(abs(z - x)) <= 1.0e3_dp*eps*maxval(abs(x)), &
                 'M⁻¹ A x = x for a tridiagonal matrix (no fill, ILU(0) = LU)')
   end subroutine test_tridiagonal

   subroutine test_laplacian(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: g = 6, n = g*g
      real(dp) :: d(n, n)
      logical :: mask(n, n)
      type(csr_t) :: a
      type(ilu0_preconditioner_t) :: m

      d = laplacian(g, 0.0_dp)
      mask = d /= 0.0_dp
      call csr_from_dense(d, mask, a)
      call m%setup(a, err)
      if (allocated(err)) return
      ! by hand: u11 = 4, l21 = −1/4, u22 = 4 − 1/4; row g+2 is eliminated by rows 2 and g+1,
      ! both with pivot 15/4 and −1 towards g+2, so u = 4 − 2·(4/15) = 52/15 (the fill at
      ! (g+1, 2) that exact LU would create is dropped)
      call check_close(err, m%factor_entry(1, 1), 4.0_dp, 4*eps, 0.0_dp, 'u(1,1)')
      call check_close(err, m%factor_entry(2, 1), -0.25_dp, 4*eps, 0.0_dp, 'l(2,1)')
      call check_close(err, m%factor_entry(2, 2), 3.75_dp, 4*eps, 0.0_dp, 'u(2,2)')
      call check_close(err, m%factor_entry(g + 1, 1), -0.25_dp, 4*eps, 0.0_dp, 'l(g+1,1)')
      call check_close(err, m%factor_entry(g + 2, 2), -1.0_dp/3.75_dp, 4*eps, 0.0_dp, 'l(g+2,2)')
      call check_close(err, m%factor_entry(g + 2, g + 1), -1.0_dp/3.75_dp, 4*eps, 0.0_dp, &
                       'l(g+2,g+1)')
      call check_close(err, m%factor_entry(g + 2, g + 2), 52.0_dp/15.0_dp, 4*eps, 0.0_dp, &
                       'u(g+2,g+2)')
      call check_close(err, m%factor_entry(g + 1, 2), 0.0_dp, 0.0_dp, 0.0_dp, 'no fill at (g+1,2)')
      call check(err, factor_difference(m, dense_ilu0(d, mask), mask) <= 16*eps*4, &
                 'every factor entry equals the dense ILU(0) on the pattern')
   end subroutine test_laplacian

   subroutine test_refactor(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: g = 5, n = g*g
      real(dp) :: d(n, n)
      logical :: mask(n, n)
      type(csr_t) :: a
      type(ilu0_preconditioner_t) :: m
      integer(ip) :: i, k

      d = laplacian(g, 0.0_dp)
      mask = d /= 0.0_dp
      call csr_from_dense(d, mask, a)
      call m%setup(a, err)
      if (allocated(err)) return
      ! new values on the same pattern: shifted diagonal and a nonsymmetric convection-like term
      d = laplacian(g, 0.7_dp)
      do i = 2, n
         if (mask(i, i - 1)) d(i, i - 1) = d(i, i - 1) - 0.3_dp
      end do
      do i = 1, a%n
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            a%val(k) = d(i, a%col(k))
         end do
      end do
      call m%setup(a, err)
      if (allocated(err)) return
      call check(err, m%n_analyses() == 1, 'same pattern: analysis kept')
      call check(err, factor_difference(m, dense_ilu0(d, mask), mask) <= 64*eps, &
                 'refactorization gives the factors of the new values')
      ! a different pattern (one extra entry) is analysed again
      mask(1, n) = .true.
      d(1, n) = 0.1_dp
      call csr_from_dense(d, mask, a)
      call m%setup(a, err)
      if (allocated(err)) return
      call check(err, m%n_analyses() == 2, 'new pattern: analysed again')
      call check(err, factor_difference(m, dense_ilu0(d, mask), mask) <= 64*eps, &
                 'factors on the new pattern')
   end subroutine test_refactor

   !> A Newton matrix on a small square with mixed active (da = 1, db = 0) and inactive
   !> (da = 0, db = 1) Newton-min rows.
   subroutine newton_matrix(levels, p, sys, active, err)
      integer, intent(in) :: levels
      type(discrete_problem_t), target, intent(out) :: p
      type(newton_system_t), intent(out) :: sys
      logical, allocatable, intent(out) :: active(:)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t) :: h
      integer(ip) :: i

      call square_problem(levels, h, p, err)
      if (allocated(err)) return
      call sys%init(p, .true.)
      ! a contact region (the left half) plus scattered active vertices elsewhere
      allocate (active(p%n))
      do i = 1, p%n
         active(i) = h%meshes(levels)%vertices(1, p%interior(i)) < 0.0_dp .or. mod(i, 7) == 0
      end do
      call sys%set_jacobian(merge(1.0_dp, 0.0_dp, active), merge(0.0_dp, 1.0_dp, active))
   end subroutine newton_matrix

   !> With set_order(keys), ILU(0) of A is that of P A Pᵀ (P: ascending keys) wrapped in P: its
   !> apply equals, bit for bit, the plain ILU(0) of the explicitly permuted matrix applied to
   !> the permuted vector, also after a refactorization on the kept pattern. The permutation is
   !> one whose ILU(0) differs from A's own (a reversed grid Laplacian with a nonsymmetric term).
   subroutine test_key_order(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: g = 5, n = g*g
      real(dp) :: d(n, n), dp_(n, n), r(n), z(n), zp(n), z_plain(n)
      logical :: mask(n, n), mask_p(n, n)
      integer(ip) :: keys(n), order(n)
      type(csr_t) :: a, ap
      type(ilu0_preconditioner_t) :: m, mp, plain
      integer(ip) :: i, j, k
      integer(i8) :: state

      d = laplacian(g, 0.3_dp)
      do i = 2, n
         if (d(i, i - 1) /= 0.0_dp) d(i, i - 1) = d(i, i - 1) - 0.2_dp
      end do
      mask = d /= 0.0_dp
      ! keys: rows interleaved from both ends, so that the order is neither A's nor its reverse
      do i = 1, n
         keys(i) = merge(2*i, 2*(n - i) + 1, mod(i, 2) == 0)
      end do
      ! order(k): the row with the k-th smallest key
      order = [(i, i=1, n)]
      do i = 2, n
         k = order(i)
         j = i - 1
         do while (j >= 1)
            if (keys(order(j)) <= keys(k)) exit
            order(j + 1) = order(j)
            j = j - 1
         end do
         order(j + 1) = k
      end do
      dp_ = d(order, order)
      mask_p = mask(order, order)
      call csr_from_dense(d, mask, a)
      call csr_from_dense(dp_, mask_p, ap)
      call m%set_order(keys)
      do k = 1, 2
         if (k == 2) then
            ! new values on the kept pattern
            d = 1.1_dp*d
            d(3, 3) = d(3, 3) + 0.05_dp
            dp_ = d(order, order)
            call csr_from_dense(d, mask, a)
            call csr_from_dense(dp_, mask_p, ap)
         end if
         call m%setup(a, err)
         if (allocated(err)) return
         call mp%setup(ap, err)
         if (allocated(err)) return
         call plain%setup(a, err)
         if (allocated(err)) return
         state = 777_i8 + k
         call fill_random(state, r)
         call m%apply(r, z)
         call mp%apply(r(order), zp)
         call plain%apply(r, z_plain)
         call check(err, all(z(order) == zp), 'ordered ILU(0) = ILU(0) of the permuted matrix, bit for bit')
         call check(err, maxval(abs(z - z_plain)) > 1.0e-6_dp*maxval(abs(z)), 'the order changes the factors')
      end do
      call check(err, m%n_analyses() == 1, 'kept pattern: analysed once')
   end subroutine test_key_order

   subroutine test_newton_matrix(err)
      type(error_t), allocatable, intent(out) :: err
      type(discrete_problem_t), target :: p
      type(newton_system_t) :: sys
      type(ilu0_preconditioner_t) :: m
      logical, allocatable :: active(:)
      real(dp), allocatable :: v(:), av(:), z(:), da(:), db(:)
      real(dp) :: expected, worst
      integer(ip) :: n, i
      integer(i8) :: state
      integer :: trial

      call newton_matrix(3, p, sys, active, err)
      if (allocated(err)) return
      n = p%n
      call check(err, count(active) > 0 .and. count(.not. active) > 0, 'both kinds of C-row')
      call check(err, sys%a%val(sys%c_pos(3, maxloc(merge(1, 0, active), 1))) == 0.0_dp, &
                 'an active row has an explicit zero diagonal')
      call m%setup(sys%a, err)
      if (allocated(err)) return
      ! the pivot of an active C-row is D_i/u(i,i) + D_i/u(n+i,n+i) = D_i (1/μ1 + 1/μ2)/s_i,
      ! an inactive one keeps 1
      do i = 1, n
         if (active(i)) then
            expected = p%mass(i)*(1.0_dp/m%factor_entry(i, i) + 1.0_dp/m%factor_entry(n + i, n + i))
            call check(err, expected > 0.0_dp, 'active pivot is positive')
         else
            expected = 1.0_dp
         end if
         call check_close(err, m%factor_entry(2*n + i, 2*n + i), expected, 16*eps, 0.0_dp, &
                          'C-row pivot')
         call check_close(err, m%factor_entry(n + i, n + i), p%mu2/p%mu1*m%factor_entry(i, i), &
                          16*eps, 0.0_dp, 'block 2 pivots are μ2/μ1 times block 1 pivots')
      end do
      call check(err, lu_matches_pattern(m, sys%a) <= 64*eps, &
                 '(L U)_ij = a_ij on the pattern (the defining property of ILU(0))')

      ! How close M⁻¹A is to I. Its eigenvalues are those of ILU(0) on S (real parts in
      ! [0.18, 1.48] on this mesh, measured), so ρ(I − M⁻¹A) < 1 and preconditioned Richardson
      ! converges (92 iterations here, about 4× more per refinement: ILU(0) leaves the O(h⁻²)
      ! conditioning of S). One product is no such measure: M⁻¹A is far from normal, since the dropped
      ! fill of a C-row (O(1)) is divided by its pivot D_i (1/μ1 + 1/μ2)/s_i = O(h²), so
      ! ‖M⁻¹Av − v‖ ≈ 14‖v‖ here for random v, growing like h⁻² (80 one level finer). What GMRES
      ! with right preconditioning sees, the residual map r ↦ r − A M⁻¹ r, does contract.
      allocate (v(3*n), av(3*n), z(3*n))
      state = 2024_i8
      worst = 0.0_dp
      do trial = 1, 5
         call fill_random(state, v)
         call m%apply(v, z)
         call sys%a%matvec(z, av)
         worst = max(worst, norm2(av - v)/norm2(v))
      end do
      call check(err, worst < 1.0_dp, 'right preconditioning contracts: ‖A M⁻¹r − r‖ < ‖r‖')
      call check(err, richardson_iterations(m, sys%a, state) <= 400, &
                 'preconditioned Richardson converges (ρ(I − M⁻¹A) < 1)')

      ! Fischer–Burmeister rows (da, −da, db) with da, db < 0, refactorized on the kept
      ! pattern: the pivot is db + da D_i (1/μ1 + 1/μ2)/s_i < 0
      da = merge(-0.3_dp, 0.0_dp, active)
      db = merge(-0.4_dp, 1.0_dp, active)
      call sys%set_jacobian(da, db)
      call m%setup(sys%a, err)
      if (allocated(err)) return
      call check(err, m%n_analyses() == 1, 'Newton refactorization keeps the analysis')
      do i = 1, n
         expected = db(i) + da(i)*p%mass(i)*(1.0_dp/m%factor_entry(i, i) + &
                                             1.0_dp/m%factor_entry(n + i, n + i))
         call check_close(err, m%factor_entry(2*n + i, 2*n + i), expected, 16*eps, 0.0_dp, &
                          'Fischer–Burmeister C-row pivot')
         call check(err, expected < 0.0_dp .or. .not. active(i), 'Fischer–Burmeister pivot < 0')
      end do
   end subroutine test_newton_matrix

   subroutine test_breakdown(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t) :: a
      type(ilu0_preconditioner_t) :: m
      type(error_t), allocatable :: e
      real(dp) :: d(3, 3), z(3)

      ! u22 = 1 − 1·1 = 0
      d = reshape([1.0_dp, 1.0_dp, 0.0_dp, 1.0_dp, 1.0_dp, 1.0_dp, 0.0_dp, 1.0_dp, 3.0_dp], [3, 3])
      call csr_from_dense(d, d /= 0.0_dp, a)
      call m%setup(a, e)
      call check(err, allocated(e), 'zero pivot is an error')
      if (allocated(err)) return
      call check(err, index(e%message, 'row 2') > 0, 'message names row 2: '//e%message)
      call check(err, e%code == exit_not_converged, 'numerical failure code')
      ! the failed preconditioner is harmless: apply is the identity
      call m%apply([1.0_dp, 2.0_dp, 3.0_dp], z)
      call check(err, all(z == [1.0_dp, 2.0_dp, 3.0_dp]), 'identity after a failed setup')
      deallocate (e)

      ! a pivot at round-off level relative to the row
      d(2, 2) = 1.0_dp + 1.0e-15_dp
      a%val(a%find(2_ip, 2_ip)) = d(2, 2)
      call m%setup(a, e)
      call check(err, allocated(e), 'tiny pivot is an error')
      if (allocated(err)) return
      call check(err, index(e%message, 'row 2') > 0, 'message names row 2: '//e%message)
      deallocate (e)

      ! the same object recovers with a good matrix on the same pattern
      a%val(a%find(2_ip, 2_ip)) = 3.0_dp
      call m%setup(a, e)
      call check(err, .not. allocated(e), 'setup succeeds after a failure')
      if (allocated(e)) deallocate (e)

      ! no (3, 3) entry in the pattern
      d(3, 3) = 0.0_dp
      call csr_from_dense(d, d /= 0.0_dp, a, with_diagonal=.false.)
      call m%setup(a, e)
      call check(err, allocated(e), 'missing diagonal is an error')
      if (allocated(err)) return
      call check(err, index(e%message, 'row 3') > 0 .and. index(e%message, 'diagonal') > 0, &
                 'message names row 3 and the diagonal: '//e%message)
   end subroutine test_breakdown

   subroutine test_jacobi(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp), parameter :: diag(5) = [2.0_dp, 0.0_dp, -4.0_dp, 0.5_dp, 0.0_dp]
      real(dp) :: d(5, 5), r(5), z(5), az(5)
      type(csr_t) :: a
      type(jacobi_preconditioner_t) :: m
      integer :: i

      d = 0.0_dp
      do i = 1, 5
         d(i, i) = diag(i)
      end do
      ! zero diagonal entries 2 (explicit) and 5 (missing from the pattern)
      call csr_from_dense(d, d /= 0.0_dp .or. reshape([(i == 7, i=1, 25)], [5, 5]), a, &
                          with_diagonal=.false.)
      call check(err, a%find(2_ip, 2_ip) > 0 .and. a%find(5_ip, 5_ip) == 0, 'test pattern')
      call m%setup(a, err)
      if (allocated(err)) return
      r = [1.0_dp, -3.0_dp, 2.0_dp, 0.25_dp, 7.0_dp]
      call m%apply(r, z)
      call a%matvec(z, az)
      do i = 1, 5
         if (diag(i) /= 0.0_dp) then
            call check_close(err, az(i), r(i), eps, 0.0_dp, 'A M⁻¹ r = r on nonzero diagonal')
         else
            call check(err, z(i) == r(i), 'zero or missing diagonal: left unscaled')
         end if
      end do
   end subroutine test_jacobi

   subroutine test_jacobi_newton(err)
      type(error_t), allocatable, intent(out) :: err
      type(discrete_problem_t), target :: p
      type(newton_system_t) :: sys
      type(jacobi_preconditioner_t) :: m
      logical, allocatable :: active(:)
      real(dp), allocatable :: r(:), z(:), d(:)
      integer(ip) :: n
      integer(i8) :: state

      call newton_matrix(2, p, sys, active, err)
      if (allocated(err)) return
      n = p%n
      call m%setup(sys%a, err)
      if (allocated(err)) return
      allocate (r(3*n), z(3*n))
      state = 77_i8
      call fill_random(state, r)
      call m%apply(r, z)
      d = sys%a%diagonal()
      call check(err, all(abs(z(1:2*n)*d(1:2*n) - r(1:2*n)) <= 4*eps*abs(r(1:2*n))), &
                 'membrane rows scaled by their diagonal')
      call check(err, all(pack(z(2*n + 1:), active) == pack(r(2*n + 1:), active)), &
                 'active C-rows (zero diagonal) unscaled')
      call check(err, all(pack(z(2*n + 1:), .not. active) == pack(r(2*n + 1:), .not. active)), &
                 'inactive C-rows (unit diagonal) unchanged')
   end subroutine test_jacobi_newton
end module test_preconditioners
