!> What the steps of one Newton solve share, and the steps themselves: `newton_state_t` holds
!> the iterate, the C-function and its Jacobian there, the Newton system and its right-hand side,
!> the linear solver with GMRES's observer, the line search, the cycling watch, the
!> Fischer–Burmeister finish and the history, with one method per part of a step: `linearize`,
!> `linear_step`, `evaluate_trial`, `take_step`, `record` (with the adaptive method's checks) and
!> `decide_stop`. `twomem_newton_solver` calls them in the order of the method.
!>
!> Who owns what: the right-hand side `b` and the Krylov workspace belong to the linear step,
!> which allocates `b` when it is absent; between two linear steps `free_linear_workspace`
!> gives both up (for the memory of an evaluation of the estimators), and nothing else frees
!> them. c, da, db hold C and its Jacobian at the last iterate whose residual was evaluated,
!> by the driver or, while GMRES runs, by its observer (which the driver does not read then).
module twomem_newton_state
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_options, only: c_function_min, c_function_fb, method_direct, method_adaptive
   use twomem_base_system, only: return_freed_memory
   use twomem_base_timer, only: wall_time
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_vectors, only: copy_into, threaded_from
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_linalg_gmres, only: gmres_stopped_by_observer, gmres_non_finite_correction
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_cfun, only: cfun_eval
   use twomem_newton_system, only: newton_system_t
   use twomem_newton_residual, only: nonlinear_residual_t
   use twomem_newton_linear, only: linear_step_t, solver_direct, solver_gmres, needs_matrix
   use twomem_newton_line_search, only: line_search_t
   use twomem_newton_cycling, only: active_set_watch_t
   use twomem_newton_fb_finish, only: fb_finish_t
   use twomem_newton_inner, only: newton_observer_t, inner_observer_t, lin_criterion
   use twomem_newton_history, only: history_t, history_row_t, not_computed, print_progress
   use twomem_newton_options, only: newton_options_t, newton_result_t, newton_status, newton_running, &
      newton_converged, newton_gmres_non_finite_correction, newton_gmres_non_finite_iterate, &
      newton_round_off_floor, newton_cycling
   implicit none
   private

   public :: newton_state_t

   !> The state of one Newton solve (a state serves one solve). Its parts point at each other
   !> (the residual at the system, GMRES's observer at the residual, c, da, db and the history;
   !> `trial` at x or x_new): a state is declared `target`, never copied, and every method takes
   !> it as a target, since GMRES and its observer write into it through those pointers.
   type :: newton_state_t
      type(discrete_problem_t), pointer :: p => null()
      type(newton_options_t) :: options
      !> the run's observer (none: disassociated)
      class(newton_observer_t), pointer :: observer => null()
      !> the adaptive method (estimator-based stopping)
      logical :: adaptive = .false.
      !> GMRES solves in place, into x: it keeps x finite (a non-finite correction is refused)
      logical :: in_place = .false.
      !> solver_direct or solver_gmres
      integer :: kind = solver_direct
      integer(ip) :: n = 0
      real(dp) :: t0 = 0.0_dp
      !> newton_running, or how the solve ended
      integer :: reason = newton_running
      type(newton_system_t) :: sys
      type(nonlinear_residual_t) :: residual
      type(linear_step_t) :: solver
      type(line_search_t) :: search
      !> the transfers of a solve on one level (multigrid is then the exact elimination)
      type(multigrid_transfer_t) :: no_transfer
      type(active_set_watch_t) :: watch
      type(fb_finish_t) :: fb
      type(inner_observer_t) :: inner
      type(history_t) :: history
      !> GMRES iterations of all linear steps so far
      integer :: linear_iterations = 0
      real(dp), allocatable :: x(:)
      !> where the linear solve writes the new iterate: x itself (GMRES without line search), or
      !> x_new where the step still needs x (the line search) or where a solver's failure could
      !> leave a non-finite x (the direct solve)
      real(dp), pointer, contiguous :: trial(:) => null()
      real(dp), allocatable :: x_new(:)
      !> C and its Jacobian (∂C/∂a, ∂C/∂b per vertex) at the last iterate evaluated
      real(dp), allocatable :: c(:), da(:), db(:)
      !> the right-hand side of the Newton system (the linear step's, see the module), and
      !> b − A x for solvers that do not return their residual
      real(dp), allocatable :: b(:), ax(:)
      !> the contact set of x and of the iterate of the row before it
      logical, allocatable :: active(:), previous(:)
      !> the merit of x (tracked by the line search)
      real(dp) :: merit_x = 0.0_dp
   contains
      procedure :: init
      procedure :: start
      procedure :: linearize
      procedure :: linear_step
      procedure :: evaluate_trial
      procedure :: take_step
      procedure :: record
      procedure :: reuses_inner_row
      procedure :: decide_stop
      procedure :: free_linear_workspace
      procedure :: finish
      procedure, private :: check_evaluates
   end type newton_state_t

contains

   !> Set up the solve of problem p from x0, which the state takes over (x0 is unallocated on
   !> return). `transfer` (the prolongations of the hierarchy whose level `level` is p's mesh;
   !> default: its finest) serves the multigrid preconditioner. Collective.
   subroutine init(self, p, options, x0, err, observer, transfer, level)
      class(newton_state_t), target, intent(inout) :: self
      type(discrete_problem_t), target, intent(in) :: p
      type(newton_options_t), intent(in) :: options
      real(dp), allocatable, intent(inout) :: x0(:)
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), target, intent(inout), optional :: observer
      type(multigrid_transfer_t), target, intent(inout), optional :: transfer
      integer, intent(in), optional :: level

      call move_alloc(x0, self%x)
      self%p => p
      self%options = options
      self%n = p%n
      self%adaptive = options%linear == method_adaptive
      if (self%adaptive .and. .not. present(observer)) then
         call make_error(err, exit_io, 'newton', 'the adaptive method needs an estimator observer')
         return
      end if
      if (present(observer)) self%observer => observer
      self%kind = merge(solver_direct, solver_gmres, options%linear == method_direct)
      call self%sys%init(p, needs_matrix(self%kind, options%precond))
      call self%residual%init(self%sys, options%cfun, track_merit=options%line_search)
      if (present(transfer)) then
         if (present(level)) then
            call self%solver%init(self%kind, options%precond, options%gmres, p, transfer, level, err)
         else
            call self%solver%init(self%kind, options%precond, options%gmres, p, transfer, transfer%levels, err)
         end if
      else
         ! one level: multigrid is the exact elimination
         call self%no_transfer%init([csr_t ::], err, halos=[p%halo], coarse_keys=p%global)
         if (.not. allocated(err)) &
            call self%solver%init(self%kind, options%precond, options%gmres, p, self%no_transfer, 0, err)
      end if
      if (allocated(err)) return
      self%in_place = self%kind == solver_gmres .and. .not. options%line_search
      allocate (self%c(self%n), self%da(self%n), self%db(self%n), self%b(3*self%n), self%active(self%n), &
                self%previous(self%n))
      if (self%in_place) then
         self%trial => self%x
      else
         allocate (self%x_new(3*self%n))
         self%trial => self%x_new
      end if
      call self%watch%init(options%max_it)
      self%fb%enabled = options%cfun == c_function_fb .and. options%fb_active_set
      self%t0 = wall_time()
      ! (an optional argument of no actual argument, a disassociated pointer or an unallocated
      ! allocatable, is absent)
      call self%inner%init(options, self%residual, self%c, self%da, self%db, self%history, self%t0, &
                           user=self%observer, prec=self%solver%prec)
   end subroutine init

   !> The row of the initial iterate, and whether it is the solution already.
   subroutine start(self)
      class(newton_state_t), target, intent(inout) :: self

      type(history_row_t) :: row

      ! before the first linearization no vertex is in contact
      self%previous = .false.
      row = not_computed()
      call self%residual%relative(self%x, row%lin_residual, self%c, self%da, self%db)
      self%merit_x = self%residual%last_merit
      call self%record(0, row, .false.)
      if (row%lin_residual <= self%options%tol) self%reason = newton_converged
   end subroutine start

   !> The C-function the next step linearizes: min in Fischer–Burmeister's active-set steps,
   !> evaluated here at x; otherwise the run's, whose Jacobian at x the last residual left in
   !> da, db.
   subroutine linearize(self)
      class(newton_state_t), target, intent(inout) :: self

      call self%fb%next_step()
      if (self%fb%active_set_step) call cfun_eval(c_function_min, self%x, self%c, self%da, self%db)
   end subroutine linearize

   !> Newton step k's linear solve, from the Jacobian in da, db into `trial`: its row with the
   !> algebraic residual, or the reason to stop when GMRES broke down (`err` when a solver failed).
   subroutine linear_step(self, k, row, err)
      class(newton_state_t), target, intent(inout) :: self
      integer, intent(in) :: k
      type(history_row_t), intent(out) :: row
      type(error_t), allocatable, intent(out) :: err

      real(dp) :: b_norm
      integer(ip) :: n

      n = self%n
      ! B = [F; J_C X − C(X)] with the Jacobian of the previous iterate
      call self%sys%set_jacobian(self%da, self%db)
      ! (after `free_linear_workspace`)
      if (.not. allocated(self%b)) allocate (self%b(3*n))
      call copy_into(self%sys%f, self%b(1:2*n))
      call complementarity_rows(self%x, self%c, self%da, self%db, self%b(2*n + 1:))
      if (.not. self%in_place) self%x_new = self%x
      b_norm = max(self%sys%dot%norm(self%b), tiny(1.0_dp))
      if (self%kind == solver_gmres) then
         call self%inner%start_solve(k, merge(c_function_min, self%options%cfun, self%fb%active_set_step), &
                                     self%linear_iterations, b_norm)
         call self%solver%solve(self%sys, self%b, self%trial, err, observer=self%inner)
         if (allocated(err)) return
         self%linear_iterations = self%linear_iterations + self%solver%monitor%iterations
         if (self%solver%monitor%reason == gmres_non_finite_correction) then
            self%reason = newton_gmres_non_finite_correction
            return
         else if (self%p%halo%comm%any_true(.not. all(ieee_is_finite(self%trial)))) then
            self%reason = newton_gmres_non_finite_iterate
            return
         end if
      else
         call self%solver%solve(self%sys, self%b, self%trial, err)
         if (allocated(err)) return
      end if
      row = not_computed()
      if (self%solver%residual_known) then
         ! GMRES ended on this very residual (an operator application and a norm saved)
         row%alg_residual = self%solver%monitor%final_residual/b_norm
      else
         ! (3n more values only for the solvers that do not return it)
         if (.not. allocated(self%ax)) allocate (self%ax(3*n))
         call self%sys%apply(self%trial, self%ax)
         self%ax = self%b - self%ax
         row%alg_residual = self%sys%dot%norm(self%ax)/b_norm
      end if
   end subroutine linear_step

   !> The last block of B: J_C X − C(X), per vertex da (X1 − X2) + db X3 − c.
   subroutine complementarity_rows(x, c, da, db, rows)
      real(dp), intent(in) :: x(:), c(:), da(:), db(:)
      real(dp), intent(out) :: rows(:)

      integer(ip) :: i, n

      n = size(c, kind=ip)
      !$omp parallel do default(none) shared(rows, x, da, db, c, n) private(i) schedule(static) if(n > threaded_from)
      do i = 1, n
         rows(i) = da(i)*(x(i) - x(n + i)) + db(i)*x(2*n + i) - c(i)
      end do
      !$omp end parallel do
   end subroutine complementarity_rows

   !> The relative residual and the merit (tracked by the line search) of the linear solve's
   !> iterate `trial`, with C and its Jacobian there in c, da, db. When GMRES was stopped by
   !> its observer, the observer's last evaluation was of this very iterate (bit for bit) and
   !> into these very arrays, and is taken as it is: one residual (a C-function, E X and three
   !> sums) less per Newton step.
   subroutine evaluate_trial(self, relative, merit)
      class(newton_state_t), target, intent(inout) :: self
      real(dp), intent(out) :: relative, merit

      logical :: observed

      ! (the direct solver leaves the monitor of no solve)
      observed = .false.
      if (self%kind == solver_gmres) observed = self%solver%monitor%reason == gmres_stopped_by_observer .and. &
                                                ieee_is_finite(self%inner%last_relative)
      if (observed) then
         relative = self%inner%last_relative
      else
         call self%residual%relative(self%trial, relative, self%c, self%da, self%db)
      end if
      merit = self%residual%last_merit
   end subroutine evaluate_trial

   !> Step k from x towards `trial` (whose relative residual and merit are given): the line
   !> search's length, the new x, and its residual in `row`.
   subroutine take_step(self, k, trial_relative, trial_merit, row)
      class(newton_state_t), target, intent(inout) :: self
      integer, intent(in) :: k
      real(dp), intent(in) :: trial_relative, trial_merit
      type(history_row_t), intent(inout) :: row

      real(dp) :: step

      step = 1.0_dp
      if (self%options%line_search) &
         step = self%search%step(self%residual, k, self%x, self%merit_x, self%x_new, trial_merit)
      if (step < 1.0_dp) call self%watch%damped(k)
      ! a full step takes GMRES's iterate itself: x + (x_new − x) differs from it by round-off,
      ! and the observer's evaluation at x_new (the last inner row) must be of this very iterate
      if (step == 1.0_dp) then
         if (.not. self%in_place) self%x = self%x_new
         ! c, da, db are those of the trial iterate
         row%lin_residual = trial_relative
         self%merit_x = trial_merit
      else
         self%x = self%x + step*(self%x_new - self%x)
         call self%residual%relative(self%x, row%lin_residual, self%c, self%da, self%db)
         self%merit_x = self%residual%last_merit
      end if
      row%step = step
   end subroutine take_step

   !> GMRES stopped by the forcing at a full step: its last inner row saw this very iterate,
   !> so the Newton row replaces it and reuses what the observer computed there.
   logical function reuses_inner_row(self, step) result(reuse)
      class(newton_state_t), target, intent(in) :: self
      real(dp), intent(in) :: step

      reuse = .false.
      if (self%history%n > 0 .and. step == 1.0_dp) then
         associate (r => self%history%rows(self%history%n))
            reuse = r%inner .and. r%gmres_it == self%linear_iterations
         end associate
      end if
   end function reuses_inner_row

   !> Append the row of step k at x (taking the observations of the last inner row when
   !> `reuse`), print its progress line, and let the cycling watch see the contact set, which
   !> the next row's changes are counted from.
   subroutine record(self, k, row, reuse)
      class(newton_state_t), target, intent(inout) :: self
      integer, intent(in) :: k
      type(history_row_t), intent(inout) :: row
      logical, intent(in) :: reuse

      logical :: estimates

      ! contact where u1 − u2 ≤ λ: for Newton-min exactly the vertices with the a-row
      call self%sys%contact_set(self%x, self%active)
      row%newton_it = k
      row%gmres_it = self%linear_iterations
      row%active = self%sys%global_count(self%active)
      row%active_changed = self%sys%global_count(self%active, other=self%previous)
      call self%watch%record(k, self%active, self%p%global, self%p%halo%owned, self%p%halo%comm)
      if (reuse) then
         call row%take_observations(self%history%rows(self%history%n))
         self%history%n = self%history%n - 1
      else if (associated(self%observer)) then
         ! Algorithm 1 reads the estimators from the first step on: at the initial iterate
         ! (at 10^6 vertices, a fifth of the adaptive run's evaluations) no test needs them
         estimates = .not. self%adaptive
         if (self%adaptive .and. k > 0) estimates = self%check_evaluates(row)
         call self%observer%observe(self%x, row, estimates=estimates)
         if (self%adaptive .and. estimates) call self%inner%schedule%remember(row)
      end if
      row%wall_time = wall_time() - self%t0
      call self%history%append(row)
      if (self%options%verbose) call print_progress(row)
      self%previous = self%active
   end subroutine record

   !> Whether the adaptive method's check at the new iterate x evaluates the estimators
   !> (check_schedule_t; a check that does not keeps what it computed in `row`).
   logical function check_evaluates(self, row) result(estimates)
      class(newton_state_t), target, intent(inout) :: self
      type(history_row_t), intent(inout) :: row

      real(dp) :: eta_lin
      logical :: last

      estimates = self%inner%schedule%screen(self%observer, self%x, row, eta_lin)
      if (.not. estimates) return
      ! η_disc at least: the idle linear workspace makes room for the evaluation's arrays
      call self%free_linear_workspace()
      call return_freed_memory()
      estimates = self%inner%schedule%decide(self%observer, self%x, row, last, screened=eta_lin, prec=self%inner%prec)
      ! a whole evaluation expected to end the run: the preconditioner's hierarchies make room
      ! for its algebraic flux too (the next solve, if any, builds them again)
      if (estimates .and. last .and. associated(self%inner%prec)) call self%inner%prec%release()
   end function check_evaluates

   !> Give up the linear step's memory between two steps: the Krylov workspace and the
   !> right-hand side, which the next `linear_step` makes again.
   subroutine free_linear_workspace(self)
      class(newton_state_t), target, intent(inout) :: self

      call self%solver%workspace%free()
      if (allocated(self%b)) deallocate (self%b)
   end subroutine free_linear_workspace

   !> Whether Newton stops after step k, whose row is `row`: `reason` becomes newton_converged
   !> or a failure, or stays newton_running.
   subroutine decide_stop(self, k, row)
      class(newton_state_t), target, intent(inout) :: self
      integer, intent(in) :: k
      type(history_row_t), intent(in) :: row

      associate (options => self%options)
         if (row%lin_residual <= options%tol) then
            self%reason = newton_converged
         else if (self%adaptive) then
            if (lin_criterion(row, options%gamma_lin, options%local_criteria)) self%reason = newton_converged
         else if (options%linear == method_direct .and. row%step == 1.0_dp .and. &
                  options%cfun == c_function_min) then
            ! exact full steps of Newton-min: a repeated active set cannot make progress
            if (row%active_changed == 0) then
               self%reason = newton_round_off_floor
            else if (self%watch%repeats(k)) then
               self%reason = newton_cycling
            end if
         end if
      end associate
   end subroutine decide_stop

   !> Hand the iterate, the history and the account of the k steps over to `result`.
   subroutine finish(self, k, result)
      class(newton_state_t), target, intent(inout) :: self
      integer, intent(in) :: k
      type(newton_result_t), intent(inout) :: result

      call move_alloc(self%x, result%x)
      result%iterations = k
      result%linear_iterations = self%linear_iterations
      result%reason = self%reason
      result%converged = self%reason == newton_converged
      result%status = newton_status(self%reason, self%solver%monitor%reason)
      if (.not. result%converged) result%status = result%status//self%solver%failure_note()
      result%history%n = self%history%n
      call move_alloc(self%history%rows, result%history%rows)
   end subroutine finish
end module twomem_newton_state
