!> Preconditioned conjugate gradients for a symmetric positive definite system A x = b, with a
!> symmetric positive definite preconditioner M ≈ A⁻¹. Like GMRES (twomem_linalg_gmres) it sees
!> the system only through `linear_operator_t`, `preconditioner_t` and `inner_product_t`, so the
!> same code runs serial, threaded or distributed (an operator that sums the ranks' parts and
!> a product over owned entries). The iteration stops on the relative residual, or on a test
!> the caller supplies (`pcg_test_t`): the estimators' Riesz problem stops when what its
!> residual costs the bound is small against what it solves for, a test no residual norm
!> expresses. Non-convergence is a reason in the monitor, not an error.
module twomem_linalg_pcg
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_linalg_operators, only: linear_operator_t, preconditioner_t, inner_product_t
   use twomem_linalg_vectors, only: threaded_from
   implicit none
   private

   public :: pcg_solve, pcg_options_t, pcg_monitor_t, pcg_test_t

   type :: pcg_options_t
      !> iterations at most (products with A after the initial residual)
      integer :: max_it = 200
      !> without a test: stop when ‖b − A x‖ ≤ max(rtol ‖b‖, atol)
      real(dp) :: rtol = 1.0e-10_dp
      real(dp) :: atol = 0.0_dp
   end type pcg_options_t

   type :: pcg_monitor_t
      integer :: iterations = 0
      !> norms of the initial residual and of the last one (the recursively updated r)
      real(dp) :: initial_residual = 0.0_dp
      real(dp) :: final_residual = 0.0_dp
      !> .true. when the residual test or the caller's test was met
      logical :: converged = .false.
      !> 'converged', 'iteration limit', 'breakdown' (pᵀ A p ≤ 0 or rᵀ M r < 0: A or M is not
      !> SPD), 'non-finite'
      character(len=:), allocatable :: reason
   end type pcg_monitor_t

   !> A stopping test: `done` sees the iterate x and its residual r = b − A x (the recursively
   !> updated one: exact in exact arithmetic) after each iteration, and at iteration 0.
   type, abstract :: pcg_test_t
   contains
      procedure(test_done), deferred :: done
   end type pcg_test_t

   abstract interface
      logical function test_done(self, iteration, x, r)
         import :: pcg_test_t, dp
         class(pcg_test_t), intent(inout) :: self
         integer, intent(in) :: iteration
         real(dp), intent(in) :: x(:), r(:)
      end function test_done
   end interface

contains

   !> x: the initial guess on entry, the last iterate on return. err only for misuse (sizes).
   subroutine pcg_solve(a, m, dot, b, x, options, monitor, err, test)
      class(linear_operator_t), intent(in) :: a
      class(preconditioner_t), intent(inout) :: m
      class(inner_product_t), intent(in) :: dot
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      type(pcg_options_t), intent(in) :: options
      type(pcg_monitor_t), intent(out) :: monitor
      type(error_t), allocatable, intent(out) :: err
      class(pcg_test_t), intent(inout), optional :: test

      real(dp), allocatable :: r(:), z(:), p(:), q(:)
      real(dp) :: rz, rz_next, pq, alpha, beta, b_norm, target
      integer(ip) :: n
      integer :: it

      n = size(b, kind=ip)
      if (size(x, kind=ip) /= n) then
         call make_error(err, exit_bad_input, 'pcg', 'the initial guess and the right-hand side differ in size')
         return
      end if
      allocate (r(n), z(n), p(n), q(n))
      call a%apply(x, q)
      call combine(b, -1.0_dp, q, r)
      b_norm = dot%norm(b)
      monitor%initial_residual = dot%norm(r)
      monitor%final_residual = monitor%initial_residual
      target = max(options%rtol*b_norm, options%atol)
      if (finished(0)) return
      call m%apply(r, z)
      rz = dot%dot(r, z)
      call copy(z, p)
      do it = 1, options%max_it
         call a%apply(p, q)
         pq = dot%dot(p, q)
         if (.not. (pq > 0.0_dp) .or. rz < 0.0_dp) then
            call stop_with(merge('non-finite', 'breakdown ', .not. (ieee_is_finite(pq) .and. ieee_is_finite(rz))))
            return
         end if
         alpha = rz/pq
         call update(x, alpha, p)
         call update(r, -alpha, q)
         monitor%iterations = it
         monitor%final_residual = dot%norm(r)
         if (.not. ieee_is_finite(monitor%final_residual)) then
            call stop_with('non-finite')
            return
         end if
         if (finished(it)) return
         call m%apply(r, z)
         rz_next = dot%dot(r, z)
         beta = rz_next/rz
         rz = rz_next
         call next_direction(p, beta, z)
      end do
      call stop_with('iteration limit')

   contains

      !> The stopping test after iteration i (0: the initial guess).
      logical function finished(i)
         integer, intent(in) :: i

         if (present(test)) then
            finished = test%done(i, x, r)
         else
            finished = monitor%final_residual <= target
         end if
         if (finished) then
            monitor%converged = .true.
            monitor%reason = 'converged'
         end if
      end function finished

      subroutine stop_with(reason)
         character(len=*), intent(in) :: reason

         monitor%converged = .false.
         monitor%reason = trim(reason)
      end subroutine stop_with
   end subroutine pcg_solve

   !> w = u + c v.
   subroutine combine(u, c, v, w)
      real(dp), intent(in) :: u(:), c, v(:)
      real(dp), intent(out) :: w(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(u, c, v, w) private(i) schedule(static) if(size(w) > threaded_from)
      do i = 1, size(w, kind=ip)
         w(i) = u(i) + c*v(i)
      end do
      !$omp end parallel do
   end subroutine combine

   !> p = z + β p.
   subroutine next_direction(p, beta, z)
      real(dp), intent(inout) :: p(:)
      real(dp), intent(in) :: beta, z(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(p, beta, z) private(i) schedule(static) if(size(p) > threaded_from)
      do i = 1, size(p, kind=ip)
         p(i) = z(i) + beta*p(i)
      end do
      !$omp end parallel do
   end subroutine next_direction

   !> y = y + c x.
   subroutine update(y, c, x)
      real(dp), intent(inout) :: y(:)
      real(dp), intent(in) :: c, x(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(y, c, x) private(i) schedule(static) if(size(y) > threaded_from)
      do i = 1, size(y, kind=ip)
         y(i) = y(i) + c*x(i)
      end do
      !$omp end parallel do
   end subroutine update

   subroutine copy(x, y)
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(x, y) private(i) schedule(static) if(size(y) > threaded_from)
      do i = 1, size(y, kind=ip)
         y(i) = x(i)
      end do
      !$omp end parallel do
   end subroutine copy
end module twomem_linalg_pcg
