!> What the Newton solver asks of GMRES's observers and of the iterate GMRES leaves it: observed
!> iterates carry the residual reported with them and a stop returns them; an observer may put
!> its work off until GMRES has freed its Krylov basis; a non-finite correction never reaches x.
!> On the Laplacian of test_gmres, with its true residuals recomputed here.
module test_gmres_observers
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use, intrinsic :: ieee_exceptions, only: ieee_get_halting_mode, ieee_set_halting_mode, ieee_invalid
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: csr_operator_t, identity_preconditioner_t
   use twomem_linalg_gmres, only: gmres_solve, gmres_options_t, gmres_monitor_t, gmres_observer_t, &
                                  gmres_workspace_t, gmres_stopped_by_observer, gmres_iteration_limit, &
                                  gmres_non_finite_correction
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_gmres, only: laplacian, load, true_residual, solve_csr, serial_product_t
   implicit none
   private

   public :: collect_gmres_observers

   !> Records what GMRES shows it and compares each iterate's true residual with the reported
   !> one, relative to the true residual but not below 10⁻⁶ ‖b‖: near 10⁻¹⁰ ‖b‖ both are
   !> dominated by the rounding in A x (~ε ‖A‖ ‖x‖). Stops once the reported residual is
   !> below `stop_below`.
   type, extends(gmres_observer_t) :: recording_observer_t
      type(csr_t), pointer :: a => null()
      real(dp), allocatable :: b(:), last_x(:)
      real(dp) :: stop_below = -1.0_dp
      integer :: every = 1, restart = 1
      integer :: calls = 0, last_iteration = 0
      logical :: on_schedule = .true.
      real(dp) :: max_mismatch = 0.0_dp, last_residual = 0.0_dp
   contains
      procedure :: observe => record_observe
   end type recording_observer_t

   !> Puts its work on the iterate of iteration `defer_at` off (`pending`), then checks on the
   !> second call that it got the same iterate, bit for bit, with GMRES's basis freed; stops
   !> there if `stop_then`. With `defer` false it stops at `defer_at` at once (the reference).
   type, extends(gmres_observer_t) :: deferring_observer_t
      integer :: defer_at = 10
      logical :: defer = .true., stop_then = .true.
      type(gmres_workspace_t), pointer :: ws => null()
      logical :: waiting = .false., finished = .false., same_iterate = .false.
      integer :: columns_then = -1, calls = 0
      real(dp), allocatable :: first_x(:)
   contains
      procedure :: observe => deferring_observe
      procedure :: pending => deferring_pending
   end type deferring_observer_t

   !> The identity for its first `healthy` applications, NaN after them: a preconditioner that
   !> breaks down in the middle of a solve.
   type, extends(identity_preconditioner_t) :: poisoned_t
      integer :: healthy = 0, applications = 0
   contains
      procedure :: apply => poisoned_apply
   end type poisoned_t

contains

   subroutine collect_gmres_observers(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('observer_iterates_and_stop', test_observer), &
               new_unittest('pending_observer_frees_the_basis', test_pending_observer), &
               new_unittest('nonfinite_correction_keeps_x', test_nonfinite_correction)]
   end subroutine collect_gmres_observers

   subroutine test_observer(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(serial_product_t) :: dot
      type(recording_observer_t) :: obs
      real(dp), allocatable :: b(:), x(:), xplain(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon, plain

      call laplacian(30_ip, a)
      b = load(a%n)
      op%a => a
      opt%restart = 25
      opt%observe_every = 10
      ! an observer that never stops sees every 10th iterate and every restart, and changes
      ! nothing
      obs = recording_observer_t(a=a, b=b, every=10, restart=25)
      allocate (x(a%n))
      x = 0.0_dp
      call gmres_solve(op, id, dot, b, x, opt, mon, err, observer=obs)
      if (allocated(err)) return
      call solve_csr(a, b, opt, xplain, plain, err, dot)
      if (allocated(err)) return
      call check(err, mon%converged, 'converged with a passive observer: '//mon%reason_text())
      call check(err, obs%calls >= mon%iterations/10, 'observer called every ν iterations')
      call check(err, obs%on_schedule, 'observer called at multiples of ν or of m, once each')
      call check(err, obs%max_mismatch <= 1.0e-8_dp, 'observed iterates have the reported residual')
      call check(err, mon%iterations == plain%iterations .and. all(x == xplain), &
                 'a passive observer changes nothing')
      if (allocated(err)) return

      ! now stop early: GMRES returns the last observed iterate
      obs = recording_observer_t(a=a, b=b, every=10, restart=25, stop_below=1.0e-4_dp*norm2(b))
      x = 0.0_dp
      call gmres_solve(op, id, dot, b, x, opt, mon, err, observer=obs)
      if (allocated(err)) return
      call check(err, mon%reason == gmres_stopped_by_observer .and. .not. mon%converged, &
                 'reason: '//mon%reason_text())
      call check(err, mon%iterations == obs%last_iteration .and. mon%iterations < plain%iterations, &
                 'stopped at the observed iteration, early')
      call check(err, obs%max_mismatch <= 1.0e-8_dp, 'observed iterates have the reported residual')
      call check(err, all(x == obs%last_x), 'x is the observed iterate')
      call check_close(err, mon%final_residual, obs%last_residual, 1.0e-8_dp, 0.0_dp, &
                       'final residual is the observed one')
      call check(err, mon%final_residual <= 1.0e-4_dp*norm2(b), 'observer criterion met')
   end subroutine test_observer

   !> An observer that puts its work off (`gmres_observer_t%pending`): GMRES ends the cycle at
   !> the same iterate, bit for bit, frees its Krylov basis and the residual (no column is left)
   !> and calls it again; a stop then returns that iterate, as a stop at once would; without a
   !> stop GMRES forms the residual again and goes on from a restart to the solution.
   subroutine test_pending_observer(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(identity_preconditioner_t) :: id
      type(serial_product_t) :: dot
      type(gmres_workspace_t), target :: ws
      type(deferring_observer_t) :: deferring, at_once
      real(dp), allocatable :: b(:), x(:), x_ref(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon, ref

      call laplacian(30_ip, a)
      op%a => a
      b = load(a%n)
      opt%restart = 30
      opt%observe_every = 5
      allocate (x(a%n), x_ref(a%n))
      at_once%defer = .false.
      x_ref = 0.0_dp
      call gmres_solve(op, id, dot, b, x_ref, opt, ref, err, observer=at_once)
      if (allocated(err)) return
      deferring%ws => ws
      x = 0.0_dp
      call gmres_solve(op, id, dot, b, x, opt, mon, err, observer=deferring, workspace=ws)
      if (allocated(err)) return
      call check(err, ref%reason == gmres_stopped_by_observer .and. ref%iterations == 10, 'reference: '//ref%reason_text())
      call check(err, mon%reason == gmres_stopped_by_observer .and. mon%iterations == 10, 'reason: '//mon%reason_text())
      call check(err, deferring%finished .and. deferring%same_iterate, 'called again with the same iterate')
      call check(err, deferring%columns_then == 0, 'the basis and the residual were freed')
      call check(err, all(x == deferring%first_x) .and. all(x == x_ref), 'x is the iterate, as a stop at once')
      if (allocated(err)) return

      deferring = deferring_observer_t(ws=ws, stop_then=.false.)
      x = 0.0_dp
      call gmres_solve(op, id, dot, b, x, opt, mon, err, observer=deferring, workspace=ws)
      if (allocated(err)) return
      call check(err, deferring%finished .and. deferring%same_iterate, 'called again with the same iterate')
      call check(err, mon%converged .and. mon%restarts >= 1, 'went on from a restart: '//mon%reason_text())
      call check(err, true_residual(a, b, x) <= 1.0e-10_dp*norm2(b)*(1 + 1.0e-6_dp), 'to the solution')
   end subroutine test_pending_observer

   !> A preconditioner that returns NaN in the second cycle: GMRES stops with 'non-finite
   !> correction' and x is the first cycle's iterate, bit for bit (Newton solves in place, in its
   !> only copy of the iterate). The reference is the same solve stopped after that cycle.
   subroutine test_nonfinite_correction(err)
      type(error_t), allocatable, intent(out) :: err
      type(csr_t), target :: a
      type(csr_operator_t) :: op
      type(poisoned_t) :: poisoned
      type(identity_preconditioner_t) :: id
      type(serial_product_t) :: dot
      real(dp), allocatable :: b(:), x(:), x_first(:)
      type(gmres_options_t) :: opt
      type(gmres_monitor_t) :: mon, first
      logical :: halting

      call laplacian(20_ip, a)
      op%a => a
      b = load(a%n)
      opt%restart = 5
      opt%max_it = 5
      allocate (x_first(a%n))
      x_first = 0.0_dp
      call gmres_solve(op, id, dot, b, x_first, opt, first, err)
      if (allocated(err)) return
      opt%max_it = 100
      poisoned%healthy = 5
      allocate (x(a%n))
      x = 0.0_dp
      ! the debug build traps invalid operations; here NaN arithmetic is the point
      call ieee_get_halting_mode(ieee_invalid, halting)
      call ieee_set_halting_mode(ieee_invalid, .false.)
      call gmres_solve(op, poisoned, dot, b, x, opt, mon, err)
      call ieee_set_halting_mode(ieee_invalid, halting)
      if (allocated(err)) return
      call check(err, first%reason == gmres_iteration_limit, 'the reference stops after one cycle: '//first%reason_text())
      call check(err, mon%reason == gmres_non_finite_correction .and. .not. mon%converged, 'reason: '//mon%reason_text())
      call check(err, poisoned%applications > poisoned%healthy, 'the second cycle ran')
      call check(err, all(x == x_first), 'x is the last finite iterate, bit for bit')
   end subroutine test_nonfinite_correction

   subroutine record_observe(self, iteration, x, residual_norm, stop)
      class(recording_observer_t), intent(inout) :: self
      integer, intent(in) :: iteration
      real(dp), intent(in) :: x(:), residual_norm
      logical, intent(out) :: stop

      real(dp) :: res

      self%calls = self%calls + 1
      if (iteration <= self%last_iteration .or. (mod(iteration, self%every) /= 0 .and. &
                                                 mod(iteration, self%restart) /= 0)) &
         self%on_schedule = .false.
      self%last_iteration = iteration
      res = true_residual(self%a, self%b, x)
      self%max_mismatch = max(self%max_mismatch, &
                              abs(res - residual_norm)/max(res, 1.0e-6_dp*norm2(self%b)))
      self%last_x = x
      self%last_residual = res
      stop = residual_norm <= self%stop_below
   end subroutine record_observe

   subroutine deferring_observe(self, iteration, x, residual_norm, stop)
      class(deferring_observer_t), intent(inout) :: self
      integer, intent(in) :: iteration
      real(dp), intent(in) :: x(:), residual_norm
      logical, intent(out) :: stop

      stop = .false.
      self%calls = self%calls + 1
      if (self%waiting) then
         self%waiting = .false.
         self%finished = .true.
         self%same_iterate = all(x == self%first_x) .and. residual_norm >= 0
         if (associated(self%ws)) self%columns_then = self%ws%columns()
         stop = self%stop_then
      else if (iteration == self%defer_at .and. .not. self%finished) then
         self%first_x = x
         if (self%defer) then
            self%waiting = .true.
         else
            self%finished = .true.
            stop = .true.
         end if
      end if
   end subroutine deferring_observe

   logical function deferring_pending(self)
      class(deferring_observer_t), intent(in) :: self

      deferring_pending = self%waiting
   end function deferring_pending

   subroutine poisoned_apply(self, r, z)
      class(poisoned_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      self%applications = self%applications + 1
      if (self%applications <= self%healthy) then
         z = r
      else
         z = ieee_value(1.0_dp, ieee_quiet_nan)
      end if
   end subroutine poisoned_apply
end module test_gmres_observers
