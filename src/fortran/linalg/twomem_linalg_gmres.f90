!> Restarted GMRES(m) with right preconditioning, the Krylov kernel behind the `gmres` and
!> `adaptive` solvers. It sees the system only through `linear_operator_t`,
!> `preconditioner_t` and `inner_product_t`, so the same code runs serial, threaded or
!> distributed. Right preconditioning (A M⁻¹ y = r₀, x = x₀ + M⁻¹ V y) makes the Arnoldi
!> residual estimate the true residual norm in exact arithmetic; convergence is nevertheless
!> decided on the true residual ‖b − A x‖, recomputed at every restart. An optional observer
!> sees the current iterate every ν iterations and may stop the solve: this is how the
!> adaptive Newton method stops GMRES on a posteriori estimators. Non-convergence is a reason
!> in the monitor (`twomem_linalg_gmres_monitor`), not an error; errors are only for misuse.
module twomem_linalg_gmres
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_linalg_operators, only: linear_operator_t, preconditioner_t, inner_product_t
   use twomem_linalg_vectors, only: copy_into, threaded_from
   use twomem_linalg_gmres_monitor, only: gmres_monitor_t, gmres_reason_text, gmres_converged, &
      gmres_iteration_limit, gmres_breakdown, gmres_stagnation, gmres_stopped_by_observer, &
      gmres_non_finite_correction, gmres_invalid_arguments, gmres_not_solved
   implicit none
   private

   public :: gmres_solve, gmres_options_t, gmres_observer_t, gmres_workspace_t
   ! how a solve ended (twomem_linalg_gmres_monitor), with the solver that tells it
   public :: gmres_monitor_t, gmres_reason_text
   public :: gmres_not_solved, gmres_converged, gmres_iteration_limit, gmres_breakdown, gmres_stagnation, &
             gmres_stopped_by_observer, gmres_non_finite_correction, gmres_invalid_arguments

   type :: gmres_options_t
      !> m: Krylov vectors per cycle
      integer :: restart = 30
      !> total Arnoldi iterations over all cycles
      integer :: max_it = 5000
      !> stop when ‖b − A x‖ ≤ max(rtol ‖b‖, atol)
      real(dp) :: rtol = 1.0e-10_dp
      real(dp) :: atol = 0.0_dp
      !> ν: the observer sees the iterate every ν iterations (and at every restart)
      integer :: observe_every = 10
      !> give up after this many consecutive cycles in which the true residual did not drop
      !> below `stagnation_factor` times its last significant value (0 disables the test)
      integer :: stagnation_window = 3
      real(dp) :: stagnation_factor = 0.999_dp
      !> h(j+1,j) ≤ breakdown_tol · ‖H(:,j)‖ is a happy breakdown (invariant Krylov space)
      real(dp) :: breakdown_tol = 100*epsilon(1.0_dp)
      !> η: a second Gram–Schmidt pass when ‖w‖ < η ‖A z_j‖ after the first (see
      !> `orthogonalize`); 0 never reorthogonalizes, a value above 1 always does
      real(dp) :: reorth_factor = 0.70710678118654752_dp
   end type gmres_options_t

   !> Receives the current iterate; set `stop` to end GMRES with x = this iterate. An observer
   !> whose work on an iterate needs the memory of GMRES's Krylov basis may put that work off:
   !> it returns without stopping and answers `pending` with .true.; GMRES then ends its cycle at
   !> that very iterate (the same bits), frees the basis and calls `observe` again with it and
   !> its true residual, where the observer finishes (and may stop). If it does not stop, GMRES
   !> goes on from a restart: the Krylov space is built anew.
   type, abstract :: gmres_observer_t
   contains
      procedure(observer_observe), deferred :: observe
      procedure :: pending => nothing_pending
   end type gmres_observer_t

   abstract interface
      !> `residual_norm` is the Arnoldi estimate inside a cycle and the true residual at a
      !> restart (equal in exact arithmetic).
      subroutine observer_observe(self, iteration, x, residual_norm, stop)
         import :: gmres_observer_t, dp
         class(gmres_observer_t), intent(inout) :: self
         integer, intent(in) :: iteration
         real(dp), intent(in) :: x(:), residual_norm
         logical, intent(out) :: stop
      end subroutine observer_observe
   end interface

   !> One vector of the Krylov basis, allocated when the iteration first reaches it.
   type :: column_t
      real(dp), allocatable :: x(:)
   end type column_t

   !> The Krylov basis V (n × (m+1)), Z = M⁻¹V (n × m) and the small Hessenberg problem. The
   !> columns are allocated when first used and kept, so a solve that converges in k ≪ m
   !> iterations holds 2k + 1 vectors, not 2m + 1, and a caller solving many systems of one size
   !> (Newton steps) keeps one workspace to reuse them. The residual is formed in V's first
   !> column and each product A z_j in the next column, so that the only other n-vector is the
   !> current iterate (a Newton system of 3·10⁶ unknowns: 24 MB a vector).
   type :: gmres_workspace_t
      private
      integer(ip) :: n = 0
      integer :: m = 0
      type(column_t), allocatable :: v(:), z(:)
      real(dp), allocatable :: h(:, :), g(:), cs(:), sn(:), y(:)
      real(dp), allocatable :: xc(:)
   contains
      procedure :: init => workspace_init
      procedure :: free => workspace_free
      procedure :: release_basis
      procedure :: columns => workspace_columns
   end type gmres_workspace_t

   !> How an Arnoldi cycle ended.
   integer, parameter :: cycle_full = 0, cycle_estimate = 1, cycle_breakdown = 2, &
                         cycle_limit = 3, cycle_stopped = 4, cycle_nonfinite = 5, cycle_pending = 6

contains

   subroutine workspace_init(self, n, m)
      class(gmres_workspace_t), intent(inout) :: self
      integer(ip), intent(in) :: n
      integer, intent(in) :: m

      call self%free()
      self%n = n
      self%m = m
      allocate (self%v(m + 1), self%z(m), self%h(m + 1, m), self%g(m + 1), self%cs(m), self%sn(m), self%y(m), &
                self%xc(n))
   end subroutine workspace_init

   !> The default observer finishes its work within `observe`.
   logical function nothing_pending(self)
      class(gmres_observer_t), intent(in) :: self

      nothing_pending = .false.
   end function nothing_pending

   !> Free the Krylov basis and the observed iterate but v(1), which holds the residual;
   !> the iteration allocates them again as it reaches them. Between solves, the caller may do
   !> the same before it needs the memory.
   subroutine release_basis(self)
      class(gmres_workspace_t), intent(inout) :: self

      integer :: j

      if (.not. allocated(self%v)) return
      do j = 2, size(self%v)
         if (allocated(self%v(j)%x)) deallocate (self%v(j)%x)
      end do
      do j = 1, size(self%z)
         if (allocated(self%z(j)%x)) deallocate (self%z(j)%x)
      end do
      if (allocated(self%xc)) deallocate (self%xc)
   end subroutine release_basis

   subroutine workspace_free(self)
      class(gmres_workspace_t), intent(inout) :: self

      if (allocated(self%v)) deallocate (self%v, self%z, self%h, self%g, self%cs, self%sn, self%y)
      if (allocated(self%xc)) deallocate (self%xc)
      self%n = 0
      self%m = 0
   end subroutine workspace_free

   !> Basis vectors held (V and Z together): what the solves so far have needed.
   integer function workspace_columns(self) result(k)
      class(gmres_workspace_t), intent(in) :: self

      integer :: j

      k = 0
      if (.not. allocated(self%v)) return
      do j = 1, size(self%v)
         if (allocated(self%v(j)%x)) k = k + 1
      end do
      do j = 1, size(self%z)
         if (allocated(self%z(j)%x)) k = k + 1
      end do
   end function workspace_columns

   !> Make sure column j exists.
   subroutine reach(columns, j, n)
      type(column_t), intent(inout) :: columns(:)
      integer, intent(in) :: j
      integer(ip), intent(in) :: n

      if (.not. allocated(columns(j)%x)) allocate (columns(j)%x(n))
   end subroutine reach

   !> Solve A x = b; `x` holds the initial guess on entry. `err` is set only for misuse
   !> (sizes, options; the monitor's reason is then gmres_invalid_arguments); how the solve ended
   !> is `monitor%reason`. A zero b returns x = 0 at once: converged, 0 iterations, zero
   !> residuals. `workspace`, if given, is (re)allocated only when n or m changed.
   subroutine gmres_solve(op, prec, dot, b, x, options, monitor, err, observer, workspace)
      class(linear_operator_t), intent(in) :: op
      class(preconditioner_t), intent(inout) :: prec
      class(inner_product_t), intent(in) :: dot
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      type(gmres_options_t), intent(in) :: options
      type(gmres_monitor_t), intent(out) :: monitor
      type(error_t), allocatable, intent(out) :: err
      class(gmres_observer_t), intent(inout), optional :: observer
      type(gmres_workspace_t), intent(inout), optional :: workspace

      type(gmres_workspace_t) :: local

      monitor%reason = gmres_invalid_arguments
      call check_arguments(size(b), size(x), options, err)
      if (allocated(err)) return
      if (present(workspace)) then
         call run_gmres(op, prec, dot, b, x, options, monitor, workspace, observer)
      else
         call run_gmres(op, prec, dot, b, x, options, monitor, local, observer)
      end if
   end subroutine gmres_solve

   subroutine check_arguments(nb, nx, opt, err)
      integer, intent(in) :: nb, nx
      type(gmres_options_t), intent(in) :: opt
      type(error_t), allocatable, intent(out) :: err

      character(len=128) :: msg

      msg = ''
      if (nx /= nb) then
         write (msg, '("size of x (",i0,") differs from size of b (",i0,")")') nx, nb
      else if (opt%restart < 1) then
         write (msg, '("restart must be at least 1, got ",i0)') opt%restart
      else if (opt%max_it < 0) then
         write (msg, '("max_it must not be negative, got ",i0)') opt%max_it
      else if (opt%observe_every < 1) then
         write (msg, '("observe_every must be at least 1, got ",i0)') opt%observe_every
      else if (opt%stagnation_window < 0) then
         write (msg, '("stagnation_window must not be negative, got ",i0)') opt%stagnation_window
      else if (.not. (opt%rtol >= 0 .and. opt%atol >= 0)) then
         msg = 'rtol and atol must not be negative'
      else if (.not. (opt%breakdown_tol >= 0 .and. opt%stagnation_factor > 0 .and. &
                      opt%reorth_factor >= 0)) then
         msg = 'breakdown_tol and reorth_factor must not be negative, '// &
               'stagnation_factor must be positive'
      end if
      if (len_trim(msg) > 0) call make_error(err, exit_bad_input, 'gmres_solve', msg)
   end subroutine check_arguments

   !> The restart loop. Every decision is taken here, at a restart point, on the true residual.
   subroutine run_gmres(op, prec, dot, b, x, opt, mon, ws, observer)
      class(linear_operator_t), intent(in) :: op
      class(preconditioner_t), intent(inout) :: prec
      class(inner_product_t), intent(in) :: dot
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      type(gmres_options_t), intent(in) :: opt
      type(gmres_monitor_t), intent(inout) :: mon
      type(gmres_workspace_t), intent(inout) :: ws
      class(gmres_observer_t), intent(inout), optional :: observer

      real(dp), allocatable :: history(:)
      real(dp) :: target, beta, reference, b_norm
      integer :: it, outcome, cycles, stalled
      logical :: stop, observed

      ! once: each norm is a pass over 3n entries (and a reduction over the ranks)
      b_norm = dot%norm(b)
      if (.not. ieee_is_finite(b_norm)) then
         ! a NaN or infinite right-hand side: nothing to solve, and nothing may be called converged
         mon%residual_history = [b_norm]
         mon%initial_residual = b_norm
         mon%final_residual = b_norm
         call finish(mon, gmres_breakdown)
         return
      else if (b_norm == 0) then
         ! x = 0 is exact whatever the guess; no operator application is needed
         x = 0.0_dp
         mon%residual_history = [0.0_dp]
         call finish(mon, gmres_converged)
         return
      end if
      if (ws%n /= size(b) .or. ws%m /= opt%restart) call ws%init(size(b, kind=ip), opt%restart)
      target = max(opt%rtol*b_norm, opt%atol)
      ! grown on demand: max_it is a safeguard, often far above what a solve takes
      allocate (history(0:min(opt%max_it, 1023)))

      call reach(ws%v, 1, ws%n)
      call residual(op, b, x, ws%v(1)%x)
      beta = dot%norm(ws%v(1)%x)
      mon%initial_residual = beta
      history(0) = beta
      it = 0
      cycles = 0
      stalled = 0
      reference = beta
      outcome = cycle_full
      do
         observed = .false.
         if (outcome == cycle_pending) then
            ! the cycle ended at the iterate the observer put its work off for: it finishes now
            call finish_put_off(stop)
            observed = .true.
            outcome = merge(cycle_stopped, cycle_full, stop)
         end if
         if (.not. ieee_is_finite(beta)) then
            call finish(mon, gmres_breakdown)
            exit
         else if (beta <= target) then
            call finish(mon, gmres_converged)
            exit
         else if (outcome == cycle_stopped) then
            call finish(mon, gmres_stopped_by_observer)
            exit
         else if (outcome == cycle_nonfinite) then
            call finish(mon, gmres_non_finite_correction)
            exit
         else if (outcome == cycle_breakdown) then
            ! the Krylov space was invariant, yet x does not meet the tolerance: rounding in
            ! the small solve or a singular operator; another cycle would rebuild the same space
            call finish(mon, gmres_breakdown)
            exit
         else if (it >= opt%max_it) then
            call finish(mon, gmres_iteration_limit)
            exit
         end if
         if (cycles > 0) then
            if (beta <= opt%stagnation_factor*reference) then
               reference = beta
               stalled = 0
            else
               stalled = stalled + 1
            end if
            if (opt%stagnation_window > 0 .and. stalled >= opt%stagnation_window) then
               call finish(mon, gmres_stagnation)
               exit
            end if
            if (present(observer) .and. .not. observed) then
               call observer%observe(it, x, beta, stop)
               ! x is the iterate already
               if (.not. stop .and. observer%pending()) call finish_put_off(stop)
               if (stop) then
                  call finish(mon, gmres_stopped_by_observer)
                  exit
               end if
            end if
            mon%restarts = mon%restarts + 1
         end if
         cycles = cycles + 1

         call arnoldi_cycle(op, prec, dot, x, beta, target, opt, ws, it, history, outcome, &
                            mon%reorthogonalizations, observer)
         call residual(op, b, x, ws%v(1)%x)
         beta = dot%norm(ws%v(1)%x)
         if (outcome == cycle_estimate .and. beta > target) &
            mon%false_convergences = mon%false_convergences + 1
         mon%happy_breakdown = outcome == cycle_breakdown
      end do
      mon%final_residual = beta
      mon%iterations = it
      mon%residual_history = history(0:it)

   contains

      !> The observer finishes the check it put off at x, with the Krylov basis freed and the
      !> residual too (its norm is beta: an evaluation that ends the run then peaks 3n values
      !> lower); the residual is formed again, the same bits, if GMRES goes on.
      subroutine finish_put_off(stop)
         logical, intent(out) :: stop

         call ws%release_basis()
         if (allocated(ws%v(1)%x)) deallocate (ws%v(1)%x)
         call observer%observe(it, x, beta, stop)
         ! (after a stop the evaluation's arrays are still there: the column waits for the next solve)
         if (stop) return
         call reach(ws%v, 1, ws%n)
         call residual(op, b, x, ws%v(1)%x)
      end subroutine finish_put_off
   end subroutine run_gmres

   subroutine finish(mon, reason)
      type(gmres_monitor_t), intent(inout) :: mon
      integer, intent(in) :: reason

      mon%reason = reason
      mon%converged = reason == gmres_converged
   end subroutine finish

   !> One cycle of at most m Arnoldi steps from the residual in ws%v(1) (norm beta); on return
   !> x = x + Z y, y minimising the residual over the cycle's Krylov space. A non-finite y (an
   !> overflow, or a preconditioner that returned NaN) leaves x as it was: the caller may solve
   !> in place, in its only copy of the iterate.
   subroutine arnoldi_cycle(op, prec, dot, x, beta, target, opt, ws, it, history, outcome, &
                            reorths, observer)
      class(linear_operator_t), intent(in) :: op
      class(preconditioner_t), intent(inout) :: prec
      class(inner_product_t), intent(in) :: dot
      real(dp), intent(inout) :: x(:)
      real(dp), intent(in) :: beta, target
      type(gmres_options_t), intent(in) :: opt
      type(gmres_workspace_t), intent(inout) :: ws
      integer, intent(inout) :: it
      real(dp), allocatable, intent(inout) :: history(:)
      integer, intent(out) :: outcome
      integer, intent(inout) :: reorths
      class(gmres_observer_t), intent(inout), optional :: observer

      integer :: j, k
      real(dp) :: colnorm, hnext, rr, estimate
      logical :: stop

      call divide(ws%v(1)%x, beta)
      ws%h = 0.0_dp
      ws%g = 0.0_dp
      ws%g(1) = beta
      k = 0
      outcome = cycle_full
      do j = 1, opt%restart
         call reach(ws%z, j, ws%n)
         call prec%apply(ws%v(j)%x, ws%z(j)%x)
         call reach(ws%v, j + 1, ws%n)
         call op%apply(ws%z(j)%x, ws%v(j + 1)%x)
         call orthogonalize(dot, ws%v(1:j), ws%v(j + 1)%x, opt%reorth_factor, ws%h(1:j + 1, j), reorths)
         ! the Hessenberg column is small and replicated, so plain Fortran is fine here
         colnorm = norm2(ws%h(1:j + 1, j))
         hnext = ws%h(j + 1, j)
         call apply_rotations(ws%cs(1:j - 1), ws%sn(1:j - 1), ws%h(1:j, j))
         rr = hypot(ws%h(j, j), hnext)
         it = it + 1
         if (rr <= opt%breakdown_tol*colnorm) then
            ! A z_j lies in the span of the earlier vectors and adds nothing: the operator is
            ! singular on this space; keep the j − 1 useful columns
            call record(history, it, abs(ws%g(j)))
            outcome = cycle_breakdown
            exit
         end if
         ws%cs(j) = ws%h(j, j)/rr
         ws%sn(j) = hnext/rr
         ws%h(j, j) = rr
         ws%h(j + 1, j) = 0.0_dp
         ws%g(j + 1) = -ws%sn(j)*ws%g(j)
         ws%g(j) = ws%cs(j)*ws%g(j)
         estimate = abs(ws%g(j + 1))
         call record(history, it, estimate)
         k = j
         if (hnext <= opt%breakdown_tol*colnorm) then
            outcome = cycle_breakdown
         else if (estimate <= target) then
            outcome = cycle_estimate
         else if (it >= opt%max_it) then
            outcome = cycle_limit
         end if
         if (outcome /= cycle_full .or. j == opt%restart) exit
         call divide(ws%v(j + 1)%x, hnext)
         ! a cycle that ends here is observed at the restart, with its true residual
         if (present(observer) .and. mod(it, opt%observe_every) == 0) then
            call current_iterate(ws, j, x)
            call observer%observe(it, ws%xc, estimate, stop)
            if (stop) then
               outcome = cycle_stopped
               exit
            else if (observer%pending()) then
               outcome = cycle_pending
               exit
            end if
         end if
      end do
      ! a cycle that ends at an observation (a stop, or a check put off) returns the very iterate
      ! the observer saw, already in xc; any other forms it from its y here
      if (outcome /= cycle_stopped .and. outcome /= cycle_pending) call current_iterate(ws, k, x)
      ! y is replicated on every rank: they all decide alike
      if (.not. all(ieee_is_finite(ws%y(1:k)))) then
         outcome = cycle_nonfinite
         return
      end if
      call copy_into(ws%xc, x)
      if (outcome == cycle_pending) call ws%release_basis()
   end subroutine arnoldi_cycle

   !> history(it) = value, doubling the array (lower bound 0) when full.
   subroutine record(history, it, value)
      real(dp), allocatable, intent(inout) :: history(:)
      integer, intent(in) :: it
      real(dp), intent(in) :: value

      real(dp), allocatable :: longer(:)

      if (it > ubound(history, 1)) then
         allocate (longer(0:2*ubound(history, 1) + 1))
         longer(0:ubound(history, 1)) = history
         call move_alloc(longer, history)
      end if
      history(it) = value
   end subroutine record

   !> Modified Gram–Schmidt of w against the j = size(v) columns of v; h(1:j) gets the
   !> coefficients, h(j+1) the norm of what is left. "Twice is enough" (Kahan–Parlett; Daniel,
   !> Gragg, Kaufman & Stewart 1976; Giraud, Langou & Rozložník 2005): if one pass shrank w below
   !> η = 1/√2 of its norm, cancellation may have cost orthogonality and a second pass restores it
   !> to working precision; a third never helps. Shifted operators (a Laplacian's large diagonal)
   !> trip this test at almost every step, doubling the orthogonalization cost, which is why η is
   !> an option.
   subroutine orthogonalize(dot, v, w, eta, h, reorths)
      class(inner_product_t), intent(in) :: dot
      !> the basis so far (w is the next column, passed apart: it is not in v)
      type(column_t), intent(in) :: v(:)
      real(dp), intent(inout) :: w(:)
      real(dp), intent(in) :: eta
      real(dp), intent(out) :: h(:)
      integer, intent(inout) :: reorths

      real(dp) :: w0, c
      integer :: i, j

      j = size(v)
      w0 = dot%norm(w)
      do i = 1, j
         h(i) = dot%dot(w, v(i)%x)
         call axpy(-h(i), v(i)%x, w)
      end do
      h(j + 1) = dot%norm(w)
      if (h(j + 1) < eta*w0) then
         reorths = reorths + 1
         do i = 1, j
            c = dot%dot(w, v(i)%x)
            h(i) = h(i) + c
            call axpy(-c, v(i)%x, w)
         end do
         h(j + 1) = dot%norm(w)
      end if
   end subroutine orthogonalize

   !> Bring a new Hessenberg column into the triangular form of the previous ones.
   pure subroutine apply_rotations(cs, sn, h)
      real(dp), intent(in) :: cs(:), sn(:)
      real(dp), intent(inout) :: h(:)

      real(dp) :: t
      integer :: i

      do i = 1, size(cs)
         t = cs(i)*h(i) + sn(i)*h(i + 1)
         h(i + 1) = -sn(i)*h(i) + cs(i)*h(i + 1)
         h(i) = t
      end do
   end subroutine apply_rotations

   !> ws%xc = x + Z(:, 1:k) y with R y = g from the rotated Hessenberg (k × k, upper
   !> triangular).
   subroutine current_iterate(ws, k, x)
      type(gmres_workspace_t), intent(inout) :: ws
      integer, intent(in) :: k
      real(dp), intent(in) :: x(:)

      integer :: i

      do i = k, 1, -1
         ws%y(i) = (ws%g(i) - sum(ws%h(i, i + 1:k)*ws%y(i + 1:k)))/ws%h(i, i)
      end do
      if (.not. allocated(ws%xc)) allocate (ws%xc(ws%n))
      call copy_into(x, ws%xc)
      do i = 1, k
         call axpy(ws%y(i), ws%z(i)%x, ws%xc)
      end do
   end subroutine current_iterate

   !> r = b − A x
   subroutine residual(op, b, x, r)
      class(linear_operator_t), intent(in) :: op
      real(dp), intent(in) :: b(:), x(:)
      real(dp), intent(out) :: r(:)

      integer(ip) :: i

      call op%apply(x, r)
      !$omp parallel do default(none) shared(b, r) private(i) schedule(static) if(size(r) > threaded_from)
      do i = 1, size(r, kind=ip)
         r(i) = b(i) - r(i)
      end do
      !$omp end parallel do
   end subroutine residual

   !> y = y + a x, threaded (the vectors are long; the Hessenberg work is not)
   subroutine axpy(a, x, y)
      real(dp), intent(in) :: a, x(:)
      real(dp), intent(inout) :: y(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(a, x, y) private(i) schedule(static) if(size(y) > threaded_from)
      do i = 1, size(y, kind=ip)
         y(i) = y(i) + a*x(i)
      end do
      !$omp end parallel do
   end subroutine axpy

   !> x = x / a (a division, as the textbook normalization: the same bits as before threading)
   subroutine divide(x, a)
      real(dp), intent(inout) :: x(:)
      real(dp), intent(in) :: a

      integer(ip) :: i

      !$omp parallel do default(none) shared(a, x) private(i) schedule(static) if(size(x) > threaded_from)
      do i = 1, size(x, kind=ip)
         x(i) = x(i)/a
      end do
      !$omp end parallel do
   end subroutine divide
end module twomem_linalg_gmres
