!> Restarted GMRES against independent references: dense Gaussian elimination on small SPD and
!> nonsymmetric matrices, true residuals recomputed here (never taken from the monitor) on a 2D
!> Laplacian, stopping reasons, breakdown, preconditioning, absolute tolerances. What the Newton
!> solver asks of GMRES's observers: test_gmres_observers.
module test_gmres
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: linear_operator_t, preconditioner_t, inner_product_t, &
                                      csr_operator_t, identity_preconditioner_t, &
                                      euclidean_product_t
   use twomem_linalg_gmres, only: gmres_solve, gmres_options_t, gmres_monitor_t, &
                                  gmres_workspace_t, gmres_converged, gmres_iteration_limit, gmres_breakdown, &
                                  gmres_stagnation
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   implicit none
   private

   public :: collect_gmres, laplacian, load, true_residual, solve_csr, serial_product_t

   !> Jacobi: M = diag(A).
   type, extends(preconditioner_t) :: jacobi_t
      real(dp), allocatable :: inv_diag(:)
   contains
      procedure :: setup => jacobi_setup
      procedure :: apply => jacobi_apply
   end type jacobi_t

   !> Partial sums over fixed blocks added in a fixed order. The threaded Euclidean product
   !> combines partial sums in whatever order the threads finish, so two identical solves agree
   !> only to rounding; tests that compare solves bit for bit use this one.
   type, extends(inner_product_t) :: serial_product_t
      integer :: block = 256
   contains
      procedure :: dot => serial_dot
   end type serial_product_t

   !> A x + δ sin(x): a slightly nonlinear, hence inexact, operator. Arnoldi's recurrence no
   !> longer describes it, so the estimate runs ahead of the true residual.
   type, extends(linear_operator_t) :: perturbed_operator_t
      type(csr_t), pointer :: a => null()
      real(dp) :: delta = 0.0_dp
   contains
      procedure :: apply => perturbed_apply
   end type perturbed_operator_t

   real(dp), parameter :: eps = epsilon(1.0_dp)

contains

   subroutine collect_gmres(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('dense_spd_vs_lu', test_dense_spd), &
               new_unittest('dense_nonsymmetric_vs_lu', test_dense_nonsymmetric), &
               new_unittest('exact_in_n_iterations', test_tiny_exact), &
               new_unittest('laplacian_true_residual', test_laplacian), &
               new_unittest('restarted_vs_full', test_restart_cost), &
               new_unittest('iteration_limit', test_limit), &
               new_unittest('breakdown_eigenvector', test_eigenvector), &
               new_unittest('breakdown_singular', test_singular), &
               new_unittest('stagnation', test_stagnation), &
               new_unittest('jacobi_preconditioner', test_jacobi), &
               new_unittest('atol_criterion', test_atol), &
               new_unittest('estimate_ahead_of_true_residual', test_inexact), &
               new_unittest('reorthogonalization_option', test_reorth), &
               new_unittest('zero_rhs', test_zero_rhs), &
               new_unittest('nan_rhs_is_a_breakdown', test_nan_rhs), &
               new_unittest('workspace_reuse', test_workspace), &
               new_unittest('misuse_is_error', test_misuse)]
   end subroutine collect_gmres

   ! ---------------------------------------------------------------- references and builders

   !> Gaussian elimination with partial pivoting: the reference solution.
   function lu_solve(a0, b) result(x)
      real(dp), intent(in) :: a0(:, :), b(:)
      real(dp) :: x(size(b))

      real(dp) :: a(size(b), size(b)), row(size(b)), t, l
      integer :: n, i, k, p

      n = size(b)
      a = a0
      x = b
      do k = 1, n
         p = maxloc(abs(a(k:n, k)), 1) + k - 1
         row = a(k, :)
         a(k, :) = a(p, :)
         a(p, :) = row
         t = x(k)
         x(k) = x(p)
         x(p) = t
         do i = k + 1, n
            l = a(i, k)/a(k, k)
            a(i, k:n) = a(i, k:n) - l*a(k, k:n)
            x(i) = x(i) - l*x(k)
         end do
      end do
      do i = n, 1, -1
         x(i) = (x(i) - sum(a(i, i + 1:n)*x(i + 1:n)))/a(i, i)
      end do
   end function lu_solve

   !> The nonzeros (and the diagonal) of a dense matrix as CSR, through init_pattern.
   subroutine dense_to_csr(d, a)
      real(dp), intent(in) :: d(:, :)
      type(csr_t), intent(out) :: a

      integer(ip), allocatable :: row_ptr(:), col(:)
      integer(ip) :: n, i, j, k

      n = size(d, 1, kind=ip)
      allocate (row_ptr(n + 1), col(n*n))
      k = 0
      row_ptr(1) = 1
      do i = 1, n
         do j = 1, n
            if (d(i, j) /= 0 .or. i == j) then
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
   end subroutine dense_to_csr

   !> Five-point stencil on an nx × nx grid of unknowns: centre, west, east, south, north;
   !> Dirichlet (neighbours outside dropped) or periodic.
   subroutine stencil_2d(nx, c, periodic, a)
      integer(ip), intent(in) :: nx
      real(dp), intent(in) :: c(5)
      logical, intent(in) :: periodic
      type(csr_t), intent(out) :: a

      integer(ip), parameter :: di(5) = [0, -1, 1, 0, 0], dj(5) = [0, 0, 0, -1, 1]
      integer(ip), allocatable :: row_ptr(:), col(:), pos(:)
      real(dp), allocatable :: v(:)
      integer(ip) :: i, j, s, ii, jj, k

      allocate (row_ptr(nx*nx + 1), col(5*nx*nx), v(5*nx*nx), pos(5*nx*nx))
      k = 0
      row_ptr(1) = 1
      do j = 1, nx
         do i = 1, nx
            do s = 1, 5
               ii = i + di(s)
               jj = j + dj(s)
               if (periodic) then
                  ii = modulo(ii - 1, nx) + 1
                  jj = modulo(jj - 1, nx) + 1
               else if (ii < 1 .or. ii > nx .or. jj < 1 .or. jj > nx) then
                  cycle
               end if
               k = k + 1
               col(k) = ii + (jj - 1)*nx
               v(k) = c(s)
            end do
            row_ptr(i + (j - 1)*nx + 1) = k + 1
         end do
      end do
      call a%init_pattern(row_ptr, col(1:k))
      do i = 1, nx*nx
         do s = row_ptr(i), row_ptr(i + 1) - 1
            pos(s) = a%find(i, col(s))
            a%val(pos(s)) = a%val(pos(s)) + v(s)
         end do
      end do
   end subroutine stencil_2d

   subroutine laplacian(nx, a)
      integer(ip), intent(in) :: nx
      type(csr_t), intent(out) :: a

      call stencil_2d(nx, [4.0_dp, -1.0_dp, -1.0_dp, -1.0_dp, -1.0_dp], .false., a)
   end subroutine laplacian

   !> A smooth load with some roughness, so that every mode is present.
   function load(n) result(b)
      integer(ip), intent(in) :: n
      real(dp) :: b(n)

      integer(ip) :: i

      b = [(1.0_dp + 0.5_dp*sin(0.37_dp*real(i, dp)), i=1, n)]
   end function load

   !> ‖b − A x‖₂ computed here, independently of GMRES.
   real(dp) function true_residual(a, b, x)
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: b(:), x(:)

      real(dp) :: ax(size(b))

      call a%matvec(x, ax)
      true_residual = norm2(b - ax)
   end function true_residual

   !> Deterministic "random" entries in [-1, 1].
   elemental real(dp) function pseudo(i, j)
      integer, intent(in) :: i, j

      pseudo = sin(real(7*i + 13*j*j + 3*i*j, dp))
   end function pseudo

   subroutine solve_dense(d, b, opt, x, mon, err)
      real(dp), intent(in) :: d(:, :), b(:)
      type(gmres_options_t), intent(in) :: opt
      real(dp), allocatable, intent(out) :: x(:)
      type(gmres_monitor_t), intent(out) :: mon
      type(error_t), allocatable, intent(out) :: err

      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(euclidean_product_t) :: dot

      call dense_to_csr(d, a)
      op%a => a
      allocate (x(size(b)))
      x = 0.0_dp
      call gmres_solve(op, id, dot, b, x, opt, mon, err)
   end subroutine solve_dense

   !> Solve the Laplacian (or any CSR system) from x = 0 without preconditioning, with the
   !> threaded Euclidean product unless told otherwise.
   subroutine solve_csr(a, b, opt, x, mon, err, product)
      type(csr_t), target, intent(in) :: a
      real(dp), intent(in) :: b(:)
      type(gmres_options_t), intent(in) :: opt
      real(dp), allocatable, intent(out) :: x(:)
      type(gmres_monitor_t), intent(out) :: mon
      type(error_t), allocatable, intent(out) :: err
      class(inner_product_t), intent(in), optional :: product

      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(euclidean_product_t) :: dot

      op%a => a
      allocate (x(size(b)))
      x = 0.0_dp
      if (present(product)) then
         call gmres_solve(op, id, product, b, x, opt, mon, err)
      else
         call gmres_solve(op, id, dot, b, x, opt, mon, err)
      end if
   end subroutine solve_csr

   ! ---------------------------------------------------------------------------- the tests

   subroutine test_dense_spd(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: n = 8
      real(dp) :: bmat(n, n), d(n, n), b(n), ref(n)
      real(dp), allocatable :: x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon
      integer :: i, j

      bmat = reshape([((pseudo(i, j), i=1, n), j=1, n)], [n, n])
      d = matmul(transpose(bmat), bmat)
      do i = 1, n
         d(i, i) = d(i, i) + 1.0_dp
      end do
      b = [(pseudo(i, 99), i=1, n)]
      ref = lu_solve(d, b)
      opt%rtol = 1.0e-13_dp
      call solve_dense(d, b, opt, x, mon, err)
      if (allocated(err)) return
      call check(err, mon%converged .and. mon%reason == gmres_converged, 'converged: '//mon%reason_text())
      call check(err, mon%iterations <= n, 'at most n iterations')
      call check(err, maxval(abs(x - ref)) <= 1.0e-10_dp*maxval(abs(ref)), 'x matches LU')
   end subroutine test_dense_spd

   subroutine test_dense_nonsymmetric(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: n = 12
      real(dp) :: d(n, n), b(n), ref(n)
      real(dp), allocatable :: x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon
      integer :: i, j

      d = reshape([((pseudo(i, j), i=1, n), j=1, n)], [n, n])
      do i = 1, n
         d(i, i) = d(i, i) + 3.0_dp
      end do
      b = [(pseudo(i, 5), i=1, n)]
      ref = lu_solve(d, b)
      opt%rtol = 1.0e-13_dp
      opt%restart = 4
      call solve_dense(d, b, opt, x, mon, err)
      if (allocated(err)) return
      call check(err, mon%converged, 'converged: '//mon%reason_text())
      call check(err, mon%restarts > 0, 'GMRES(4) on n = 12 restarts')
      call check(err, maxval(abs(x - ref)) <= 1.0e-10_dp*maxval(abs(ref)), 'x matches LU')
   end subroutine test_dense_nonsymmetric

   !> In exact arithmetic the Krylov space of a 5 × 5 system is all of R⁵ after 5 steps.
   subroutine test_tiny_exact(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: n = 5
      real(dp) :: d(n, n), b(n), ref(n)
      real(dp), allocatable :: x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon
      integer :: i, j

      d = reshape([((pseudo(i, j) + merge(1.5_dp, 0.0_dp, i == j), i=1, n), j=1, n)], [n, n])
      b = [(real(i, dp), i=1, n)]
      ref = lu_solve(d, b)
      opt%rtol = 1.0e-14_dp
      opt%restart = n
      call solve_dense(d, b, opt, x, mon, err)
      if (allocated(err)) return
      call check(err, mon%converged, 'converged: '//mon%reason_text())
      call check(err, mon%iterations <= n .and. mon%restarts == 0, 'at most n iterations, no restart')
      call check(err, size(mon%residual_history) == mon%iterations + 1, 'history length')
      call check(err, maxval(abs(x - ref)) <= 1.0e-12_dp*maxval(abs(ref)), 'x matches LU')
   end subroutine test_tiny_exact

   subroutine test_laplacian(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      real(dp), allocatable :: b(:), x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon
      real(dp) :: res

      call laplacian(40_ip, a)
      b = load(a%n)
      call solve_csr(a, b, opt, x, mon, err)
      if (allocated(err)) return
      res = true_residual(a, b, x)
      call check(err, mon%converged .and. mon%reason == gmres_converged, 'converged: '//mon%reason_text())
      call check(err, res <= (1.0_dp + 1.0e-6_dp)*1.0e-10_dp*norm2(b), 'true residual ≤ rtol ‖b‖')
      call check_close(err, mon%final_residual, res, 1.0e-6_dp, 0.0_dp, 'final_residual')
      call check_close(err, mon%initial_residual, norm2(b), 100*eps, 0.0_dp, 'initial_residual')
      call check(err, size(mon%residual_history) == mon%iterations + 1, 'history length')
      if (allocated(err)) return
      call check_close(err, mon%residual_history(1), norm2(b), 100*eps, 0.0_dp, 'history starts at ‖b‖')
      call check(err, mon%restarts > 0, 'GMRES(30) restarts on the Laplacian')
   end subroutine test_laplacian

   subroutine test_restart_cost(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      real(dp), allocatable :: b(:), x(:), xfull(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon, full

      call laplacian(40_ip, a)
      b = load(a%n)
      opt%restart = 10
      call solve_csr(a, b, opt, x, mon, err)
      if (allocated(err)) return
      opt%restart = 600
      call solve_csr(a, b, opt, xfull, full, err)
      if (allocated(err)) return
      call check(err, mon%converged .and. full%converged, 'both converge')
      call check(err, full%restarts == 0, 'GMRES(600) does not restart')
      call check(err, mon%iterations > full%iterations, 'restarting costs iterations')
      ! full GMRES minimises over a growing space: its estimates never increase
      call check(err, all(full%residual_history(2:) <= full%residual_history(:full%iterations)), &
                 'full GMRES residual is monotone')
      call check(err, true_residual(a, b, x) <= 1.0e-10_dp*norm2(b)*(1 + 1.0e-6_dp) .and. &
                 true_residual(a, b, xfull) <= 1.0e-10_dp*norm2(b)*(1 + 1.0e-6_dp), 'true residuals')
   end subroutine test_restart_cost

   subroutine test_limit(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      real(dp), allocatable :: b(:), x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      call laplacian(40_ip, a)
      b = load(a%n)
      opt%max_it = 20
      opt%restart = 8
      call solve_csr(a, b, opt, x, mon, err)
      if (allocated(err)) return
      call check(err, .not. mon%converged .and. mon%reason == gmres_iteration_limit, 'reason: '//mon%reason_text())
      call check(err, mon%iterations == 20 .and. size(mon%residual_history) == 21, 'counts')
      call check_close(err, mon%final_residual, true_residual(a, b, x), 1.0e-10_dp, 0.0_dp, &
                       'final residual is the true one')
      call check(err, mon%final_residual < mon%initial_residual, 'progress was made')
      if (allocated(err)) return
      opt%max_it = 0
      call solve_csr(a, b, opt, x, mon, err)
      if (allocated(err)) return
      call check(err, mon%reason == gmres_iteration_limit .and. mon%iterations == 0 .and. all(x == 0), &
                 'max_it = 0 returns the guess')
   end subroutine test_limit

   !> A periodic convection–diffusion stencil with row sums 1: b = 3·(1, …, 1) is an
   !> eigenvector, the Krylov space is invariant after one step.
   subroutine test_eigenvector(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      real(dp), allocatable :: b(:), x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      call stencil_2d(10_ip, [6.0_dp, -2.0_dp, -1.0_dp, -1.0_dp, -1.0_dp], .true., a)
      allocate (b(a%n))
      b = 3.0_dp
      opt%rtol = 1.0e-14_dp
      call solve_csr(a, b, opt, x, mon, err)
      if (allocated(err)) return
      call check(err, mon%converged .and. mon%iterations == 1, 'one iteration')
      call check(err, mon%happy_breakdown, 'detected as a happy breakdown')
      call check(err, maxval(abs(x - 3.0_dp)) <= 100*eps, 'x = b')
   end subroutine test_eigenvector

   !> A = diag(1, 0), b = (1, 1): the second Krylov vector adds nothing (A singular), GMRES
   !> returns the least-squares solution (1, 1) with residual 1 and reports the breakdown.
   subroutine test_singular(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp), allocatable :: x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      call solve_dense(reshape([1.0_dp, 0.0_dp, 0.0_dp, 0.0_dp], [2, 2]), [1.0_dp, 1.0_dp], &
                       opt, x, mon, err)
      if (allocated(err)) return
      call check(err, .not. mon%converged .and. mon%reason == gmres_breakdown, 'reason: '//mon%reason_text())
      call check(err, mon%iterations == 2, 'two iterations')
      call check_close(err, mon%final_residual, 1.0_dp, 1.0e-14_dp, 0.0_dp, 'least-squares residual')
      call check(err, maxval(abs(x - 1.0_dp)) <= 10*eps, 'least-squares solution')
   end subroutine test_singular

   !> GMRES(1) on a rotation: (r, A r) = 0, so no cycle makes progress.
   subroutine test_stagnation(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp), allocatable :: x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      opt%restart = 1
      call solve_dense(reshape([0.0_dp, -1.0_dp, 1.0_dp, 0.0_dp], [2, 2]), [1.0_dp, 0.0_dp], &
                       opt, x, mon, err)
      if (allocated(err)) return
      call check(err, .not. mon%converged .and. mon%reason == gmres_stagnation, 'reason: '//mon%reason_text())
      call check(err, mon%iterations == 3 .and. mon%restarts == 2, 'three cycles')
   end subroutine test_stagnation

   !> Column scaling by factors 1 … 10⁴ of a nonsymmetric diagonally dominant tridiagonal
   !> matrix: right Jacobi preconditioning undoes it exactly.
   subroutine test_jacobi(err)
      type(error_t), allocatable, intent(out) :: err
      integer(ip), parameter :: n = 400
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(jacobi_t) :: jac
      type(euclidean_product_t) :: dot
      real(dp), allocatable :: b(:), x(:)
      integer(ip) :: row_ptr(n + 1), col(3*n - 2)
      real(dp) :: scale(n)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: plain, pre
      integer(ip) :: i, k

      row_ptr = [1_ip, [(3*i, i=1, n - 1)], 3*n - 1]
      col = [1_ip, 2_ip, [((i + k, k=-1, 1), i=2, n - 1)], n - 1, n]
      call a%init_pattern(row_ptr, col)
      scale = [(10.0_dp**(4*real(modulo(37*i, 101), dp)/100), i=1, n)]
      do i = 1, n
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            a%val(k) = merge(4.0_dp, merge(-1.0_dp, -2.0_dp, a%col(k) < i), a%col(k) == i) &
                       *scale(a%col(k))
         end do
      end do
      op%a => a
      b = load(n)
      allocate (x(n))
      x = 0.0_dp
      opt%max_it = 2000
      call gmres_solve(op, id, dot, b, x, opt, plain, err)
      if (allocated(err)) return
      call jac%setup(a, err)
      if (allocated(err)) return
      x = 0.0_dp
      call gmres_solve(op, jac, dot, b, x, opt, pre, err)
      if (allocated(err)) return
      call check(err, pre%converged, 'Jacobi-preconditioned GMRES converges: '//pre%reason_text())
      call check(err, true_residual(a, b, x) <= 1.0e-10_dp*norm2(b)*(1 + 1.0e-6_dp), 'true residual')
      call check(err, 3*pre%iterations < plain%iterations, 'Jacobi cuts the iterations')
   end subroutine test_jacobi

   subroutine test_atol(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      real(dp), allocatable :: b(:), x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: tight, loose

      call laplacian(40_ip, a)
      b = load(a%n)
      call solve_csr(a, b, opt, x, tight, err)
      if (allocated(err)) return
      opt%rtol = 0.0_dp
      opt%atol = 1.0e-3_dp
      call solve_csr(a, b, opt, x, loose, err)
      if (allocated(err)) return
      call check(err, loose%converged, 'converged on atol: '//loose%reason_text())
      call check(err, true_residual(a, b, x) <= 1.0e-3_dp*(1 + 1.0e-6_dp), 'true residual ≤ atol')
      call check(err, loose%iterations < tight%iterations, 'atol target reached earlier')
      if (allocated(err)) return
      ! the looser of the two targets wins
      opt%rtol = 1.0e-10_dp
      call solve_csr(a, b, opt, x, loose, err)
      if (allocated(err)) return
      call check(err, loose%converged .and. loose%iterations < tight%iterations, &
                 'max(rtol ‖b‖, atol) is the target')
   end subroutine test_atol

   !> The Arnoldi estimate of an inexact operator claims convergence the true residual does
   !> not confirm: GMRES records it and restarts until the true residual meets the tolerance.
   subroutine test_inexact(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(perturbed_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(euclidean_product_t) :: dot
      real(dp), allocatable :: b(:), x(:), ax(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      call laplacian(20_ip, a)
      op%a => a
      op%delta = 1.0e-6_dp
      b = load(a%n)
      allocate (x(a%n), ax(a%n))
      x = 0.0_dp
      opt%restart = 400
      call gmres_solve(op, id, dot, b, x, opt, mon, err)
      if (allocated(err)) return
      call check(err, mon%converged, 'converged: '//mon%reason_text())
      call check(err, mon%false_convergences >= 1 .and. mon%restarts >= 1, &
                 'false convergence recorded and followed by a restart')
      call op%apply(x, ax)
      call check(err, norm2(b - ax) <= 1.0e-10_dp*norm2(b)*(1 + 1.0e-6_dp), 'true residual')
   end subroutine test_inexact

   !> η = 0 never takes the second Gram–Schmidt pass, η = 2 always does; both converge.
   subroutine test_reorth(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      real(dp), allocatable :: b(:), x(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: never, always

      call laplacian(20_ip, a)
      b = load(a%n)
      opt%reorth_factor = 0.0_dp
      call solve_csr(a, b, opt, x, never, err)
      if (allocated(err)) return
      opt%reorth_factor = 2.0_dp
      call solve_csr(a, b, opt, x, always, err)
      if (allocated(err)) return
      call check(err, never%converged .and. always%converged, 'both converge')
      call check(err, never%reorthogonalizations == 0, 'η = 0: no second pass')
      call check(err, always%reorthogonalizations == always%iterations, 'η = 2: every step')
      call check(err, abs(never%iterations - always%iterations) <= 2, 'same convergence')
   end subroutine test_reorth

   subroutine test_zero_rhs(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(euclidean_product_t) :: dot
      real(dp) :: x(100)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      call laplacian(10_ip, a)
      op%a => a
      x = 1.0_dp
      call gmres_solve(op, id, dot, spread(0.0_dp, 1, 100), x, opt, mon, err)
      if (allocated(err)) return
      call check(err, all(x == 0) .and. mon%converged .and. mon%iterations == 0, 'x = 0, converged')
      call check(err, size(mon%residual_history) == 1, 'history holds the initial residual')
   end subroutine test_zero_rhs

   !> A NaN in b must never end as 'converged' (its norm must not be taken for zero).
   subroutine test_nan_rhs(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(euclidean_product_t) :: dot
      real(dp) :: x(100), b(100)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon

      call laplacian(10_ip, a)
      op%a => a
      x = 1.0_dp
      b = 1.0_dp
      b(37) = ieee_value(1.0_dp, ieee_quiet_nan)
      call gmres_solve(op, id, dot, b, x, opt, mon, err)
      if (allocated(err)) return
      call check(err, .not. mon%converged .and. mon%reason == gmres_breakdown, &
                 'NaN right-hand side: breakdown, got '//mon%reason_text())
      call check(err, all(x == 1.0_dp), 'x left as it was')
   end subroutine test_nan_rhs

   !> One workspace across solves (and a change of m) gives the same answers as none.
   subroutine test_workspace(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(serial_product_t) :: dot
      type(gmres_workspace_t) :: ws
      real(dp), allocatable :: b(:), x(:), xref(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon, ref
      integer :: m

      call laplacian(20_ip, a)
      op%a => a
      b = load(a%n)
      allocate (x(a%n))
      do m = 10, 30, 10
         opt%restart = m
         call solve_csr(a, b, opt, xref, ref, err, dot)
         if (allocated(err)) return
         x = 0.0_dp
         call gmres_solve(op, id, dot, b, x, opt, mon, err, workspace=ws)
         if (allocated(err)) return
         x = 0.0_dp
         call gmres_solve(op, id, dot, b, x, opt, mon, err, workspace=ws)
         if (allocated(err)) return
         call check(err, mon%iterations == ref%iterations .and. all(x == xref), 'same solve')
         if (allocated(err)) return
      end do
      call ws%free()
   end subroutine test_workspace

   subroutine test_misuse(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(euclidean_product_t) :: dot
      real(dp) :: x(99), y(100)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon
      type(error_t), allocatable :: e

      call laplacian(10_ip, a)
      op%a => a
      x = 0.0_dp
      call gmres_solve(op, id, dot, spread(1.0_dp, 1, 100), x, opt, mon, e)
      call check(err, allocated(e), 'size mismatch is an error')
      if (allocated(err)) return
      call check(err, index(e%message, 'gmres_solve') > 0, 'message names the routine: '//e%message)
      y = 0.0_dp
      opt%restart = 0
      call gmres_solve(op, id, dot, spread(1.0_dp, 1, 100), y, opt, mon, e)
      call check(err, allocated(e), 'restart = 0 is an error')
      opt%restart = 30
      opt%rtol = -1.0_dp
      call gmres_solve(op, id, dot, spread(1.0_dp, 1, 100), y, opt, mon, e)
      call check(err, allocated(e), 'negative rtol is an error')
   end subroutine test_misuse

   ! --------------------------------------------------------------- test-local extensions

   subroutine jacobi_setup(self, a, err)
      class(jacobi_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      self%inv_diag = 1.0_dp/a%diagonal()
   end subroutine jacobi_setup

   subroutine jacobi_apply(self, r, z)
      class(jacobi_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      z = self%inv_diag*r
   end subroutine jacobi_apply

   real(dp) function serial_dot(self, x, y) result(s)
      class(serial_product_t), intent(in) :: self
      real(dp), intent(in) :: x(:), y(:)

      integer :: i

      s = 0.0_dp
      do i = 1, size(x), self%block
         s = s + sum(x(i:min(i + self%block - 1, size(x)))*y(i:min(i + self%block - 1, size(x))))
      end do
   end function serial_dot

   subroutine perturbed_apply(self, x, y)
      class(perturbed_operator_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      call self%a%matvec(x, y)
      y = y + self%delta*sin(x)
   end subroutine perturbed_apply

end module test_gmres
