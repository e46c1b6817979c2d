!> The semismooth Newton driver. Each step linearizes the C-function at the current iterate,
!> solves the Newton system (exactly with UMFPACK, or by GMRES) and checks the paper's stopping
!> test ‖R_lin‖/‖[F;0]‖ ≤ tol with R_lin = [F − E X; −C(X)] (docs/method.md §2). With GMRES the
!> inner observer (`twomem_newton_inner`) records every ν iterations and stops GMRES by the
!> paper's forcing or, in the adaptive mode (the paper's Algorithm 1), by the estimators that
!> the run's observer computes; Newton then stops when η_lin ≤ γ_lin η_disc. An optional
!> backtracking line search (`twomem_newton_line_search`) keeps Newton from cycling or
!> diverging (on by default for Fischer–Burmeister). The driver stops with a reason at the step
!> limit, when exact Newton-min revisits an active set (`twomem_newton_cycling`) or when the
!> active set stops changing with the residual above the tolerance (round-off floor).
!>
!> Fischer–Burmeister finishes with Newton-min (active-set) steps once its contact set settles,
!> unless told not to (`twomem_newton_fb_finish`). The loop reads as the method: linearize,
!> solve (`linear_step`), step (line search), record (`record`, which asks the observer and, in
!> the adaptive method, lets `check_schedule_t` decide what a check computes) and decide
!> (`decide_stop`).
module twomem_newton_solver
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_options, only: c_function_min, c_function_fb, method_direct, method_adaptive
   use twomem_base_system, only: return_freed_memory
   use twomem_base_timer, only: wall_time
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_vectors, only: copy_into, threaded_from
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_linalg_gmres, only: gmres_options_t, gmres_stopped_by_observer, gmres_non_finite_correction
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_cfun, only: cfun_eval
   use twomem_newton_system, only: newton_system_t
   use twomem_newton_residual, only: nonlinear_residual_t
   use twomem_newton_linear, only: linear_step_t, solver_direct, solver_gmres, needs_matrix
   use twomem_newton_line_search, only: line_search_t
   use twomem_newton_cycling, only: active_set_watch_t
   use twomem_newton_fb_finish, only: fb_finish_t
   use twomem_newton_inner, only: newton_observer_t, inner_observer_t, lin_criterion
   use twomem_newton_history, only: history_row_t, not_computed, print_progress
   use twomem_newton_options, only: newton_options_t, newton_result_t, automatic_every, newton_status, &
      newton_running, newton_converged, newton_iteration_limit, newton_gmres_non_finite_correction, &
      newton_gmres_non_finite_iterate, newton_round_off_floor, newton_cycling
   implicit none
   private

   public :: newton_solve
   ! what a solve is asked and answers, with the solver
   public :: newton_options_t, newton_result_t, newton_observer_t, automatic_every


contains

   !> Newton for problem p from x0, which it takes over (x0 is unallocated on return; at 10^6
   !> vertices the finest level's start is 23 MiB that would otherwise sit beside the iterate
   !> through the whole solve). `transfer` (the prolongations of the hierarchy whose level
   !> `level` is p's mesh; default: its finest) serves the multigrid preconditioner. Collective:
   !> in a distributed run every rank calls it with its piece of the problem.
   subroutine newton_solve(p, options, x0, result, err, observer, transfer, level)
      type(discrete_problem_t), target, intent(in) :: p
      type(newton_options_t), intent(in) :: options
      real(dp), allocatable, intent(inout) :: x0(:)
      type(newton_result_t), target, intent(out) :: result
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), intent(inout), target, optional :: observer
      type(multigrid_transfer_t), target, intent(inout), optional :: transfer
      integer, intent(in), optional :: level

      type(newton_system_t), target :: sys
      type(nonlinear_residual_t), target :: residual
      type(linear_step_t), target :: solver
      type(line_search_t) :: search
      type(multigrid_transfer_t), target :: no_transfer
      type(active_set_watch_t) :: watch
      type(fb_finish_t) :: fb
      type(inner_observer_t) :: inner
      type(history_row_t) :: row
      real(dp), allocatable, target :: x(:), x_new(:)
      real(dp), allocatable :: b(:), ax(:)
      !> where the linear solve writes the new iterate: x itself (GMRES without line search), or
      !> x_new where the step still needs x (the line search) or where a solver's failure could
      !> leave a non-finite x (the direct solve)
      real(dp), pointer, contiguous :: trial(:)
      real(dp), allocatable, target :: c(:), da(:), db(:)
      logical, allocatable :: active(:), previous(:)
      integer(ip) :: n
      integer :: k, kind
      !> the relative residual and merit of GMRES's (or UMFPACK's) iterate, and the merit of x
      real(dp) :: t0, step, trial_relative, trial_merit, merit_x
      !> newton_running, or how the solve ended
      integer :: reason
      logical :: adaptive, in_place

      call move_alloc(x0, x)
      reason = newton_running
      n = p%n
      adaptive = options%linear == method_adaptive
      if (adaptive .and. .not. present(observer)) then
         call make_error(err, exit_io, 'newton', 'the adaptive method needs an estimator observer')
         return
      end if
      kind = merge(solver_direct, solver_gmres, options%linear == method_direct)
      call sys%init(p, needs_matrix(kind, options%precond))
      call residual%init(sys, options%cfun, track_merit=options%line_search)
      if (present(transfer)) then
         if (present(level)) then
            call solver%init(kind, options%precond, options%gmres, p, transfer, level, err)
         else
            call solver%init(kind, options%precond, options%gmres, p, transfer, transfer%levels, err)
         end if
      else
         ! one level: multigrid is the exact elimination
         call no_transfer%init([csr_t ::], err, halos=[p%halo], coarse_keys=p%global)
         if (.not. allocated(err)) call solver%init(kind, options%precond, options%gmres, p, no_transfer, 0, err)
      end if
      if (allocated(err)) return
      ! in place, GMRES keeps x finite (a non-finite correction is refused): 3n values fewer
      in_place = kind == solver_gmres .and. .not. options%line_search
      allocate (c(n), da(n), db(n), b(3*n), active(n), previous(n))
      if (in_place) then
         trial => x
      else
         allocate (x_new(3*n))
         trial => x_new
      end if
      call watch%init(options%max_it)
      fb%enabled = options%cfun == c_function_fb .and. options%fb_active_set
      t0 = wall_time()
      ! before the first linearization no vertex is in contact
      previous = .false.

      row = not_computed()
      call residual%relative(x, row%lin_residual, c, da, db)
      merit_x = residual%last_merit
      call record(0, row, .false.)
      previous = active
      if (row%lin_residual <= options%tol) reason = newton_converged
      ! (an absent `observer`, or an unallocated preconditioner (the direct solver's), is absent)
      call inner%init(options, residual, c, da, db, result%history, t0, user=observer, prec=solver%prec)

      k = 0
      do while (reason == newton_running)
         if (k == options%max_it) then
            reason = newton_iteration_limit
            exit
         end if
         k = k + 1
         call fb%next_step()
         if (fb%active_set_step) call cfun_eval(c_function_min, x, c, da, db)
         call linear_step(k, row)
         if (allocated(err)) return
         if (reason /= newton_running) exit
         call evaluate_trial(trial_relative, trial_merit)
         step = 1.0_dp
         if (options%line_search) step = search%step(residual, k, x, merit_x, x_new, trial_merit)
         if (step < 1.0_dp) call watch%damped(k)
         ! a full step takes GMRES's iterate itself: x + (x_new − x) differs from it by round-off,
         ! and the observer's evaluation at x_new (the last inner row) must be of this very iterate
         if (step == 1.0_dp) then
            if (.not. in_place) x = x_new
            ! c, da, db are those of the trial iterate
            row%lin_residual = trial_relative
            merit_x = trial_merit
         else
            x = x + step*(x_new - x)
            call residual%relative(x, row%lin_residual, c, da, db)
            merit_x = residual%last_merit
         end if
         row%step = step
         call record(k, row, reuses_inner_row(step))
         call fb%step_moved(row%active_changed, row%active)
         call decide_stop(row, k)
         previous = active
      end do

      call move_alloc(x, result%x)
      result%iterations = k
      result%reason = reason
      result%converged = reason == newton_converged
      result%status = newton_status(reason, solver%monitor%reason)
      if (.not. result%converged) result%status = result%status//solver%failure_note()

   contains

      !> Newton step k's linear solve, from the Jacobian in da, db into `trial`: its row with the
      !> algebraic residual, or the `reason` to stop when GMRES broke down (`err` when a solver failed).
      subroutine linear_step(k, row)
         integer, intent(in) :: k
         type(history_row_t), intent(out) :: row

         real(dp) :: b_norm
         integer(ip) :: i

         ! B = [F; J_C X − C(X)] with the Jacobian of the previous iterate
         call sys%set_jacobian(da, db)
         ! (an evaluation of the estimators between the steps may have taken its memory)
         if (.not. allocated(b)) allocate (b(3*n))
         call copy_into(sys%f, b(1:2*n))
         !$omp parallel do default(none) shared(b, x, da, db, c, n) private(i) schedule(static) if(n > threaded_from)
         do i = 1, n
            b(2*n + i) = da(i)*(x(i) - x(n + i)) + db(i)*x(2*n + i) - c(i)
         end do
         !$omp end parallel do
         if (.not. in_place) x_new = x
         b_norm = max(sys%dot%norm(b), tiny(1.0_dp))
         if (kind == solver_gmres) then
            call inner%start_solve(k, merge(c_function_min, options%cfun, fb%active_set_step), &
                                   result%linear_iterations, b_norm)
            call solver%solve(sys, b, trial, err, observer=inner)
            if (allocated(err)) return
            result%linear_iterations = result%linear_iterations + solver%monitor%iterations
            if (solver%monitor%reason == gmres_non_finite_correction) then
               reason = newton_gmres_non_finite_correction
               return
            else if (p%halo%comm%any_true(.not. all(ieee_is_finite(trial)))) then
               reason = newton_gmres_non_finite_iterate
               return
            end if
         else
            call solver%solve(sys, b, trial, err)
            if (allocated(err)) return
         end if
         row = not_computed()
         if (solver%residual_known) then
            ! GMRES ended on this very residual (an operator application and a norm saved)
            row%alg_residual = solver%monitor%final_residual/b_norm
         else
            ! (3n more values only for the solvers that do not return it)
            if (.not. allocated(ax)) allocate (ax(3*n))
            call sys%apply(trial, ax)
            ax = b - ax
            row%alg_residual = sys%dot%norm(ax)/b_norm
         end if
      end subroutine linear_step

      !> The relative residual and the merit (tracked by the line search) of the linear solve's
      !> iterate `trial`, with C and its Jacobian there in c, da, db. When GMRES was stopped by
      !> its observer, the observer's last evaluation was of this very iterate (bit for bit) and
      !> into these very arrays, and is taken as it is: one residual (a C-function, E X and three
      !> sums) less per Newton step.
      subroutine evaluate_trial(relative, merit)
         real(dp), intent(out) :: relative, merit

         logical :: observed

         ! (the direct solver leaves the monitor of no solve)
         observed = .false.
         if (kind == solver_gmres) observed = solver%monitor%reason == gmres_stopped_by_observer .and. &
                                              ieee_is_finite(inner%last_relative)
         if (observed) then
            relative = inner%last_relative
         else
            call residual%relative(trial, relative, c, da, db)
         end if
         merit = residual%last_merit
      end subroutine evaluate_trial

      !> GMRES stopped by the forcing at a full step: its last inner row saw this very iterate,
      !> so the Newton row replaces it and reuses what the observer computed there.
      logical function reuses_inner_row(step) result(reuse)
         real(dp), intent(in) :: step

         reuse = .false.
         if (result%history%n > 0 .and. step == 1.0_dp) then
            associate (r => result%history%rows(result%history%n))
               reuse = r%inner .and. r%gmres_it == result%linear_iterations
            end associate
         end if
      end function reuses_inner_row

      !> Whether Newton stops after step k: `reason` becomes newton_converged or a failure, or
      !> stays newton_running.
      subroutine decide_stop(row, k)
         type(history_row_t), intent(in) :: row
         integer, intent(in) :: k

         if (row%lin_residual <= options%tol) then
            reason = newton_converged
         else if (adaptive) then
            if (lin_criterion(row, options%gamma_lin, options%local_criteria)) reason = newton_converged
         else if (options%linear == method_direct .and. row%step == 1.0_dp .and. &
                  options%cfun == c_function_min) then
            ! exact full steps of Newton-min: a repeated active set cannot make progress
            if (row%active_changed == 0) then
               reason = newton_round_off_floor
            else if (watch%repeats(k)) then
               reason = newton_cycling
            end if
         end if
      end subroutine decide_stop

      !> Append the row of step k (taking the observations of the last inner row when `reuse`).
      subroutine record(k, row, reuse)
         integer, intent(in) :: k
         type(history_row_t), intent(inout) :: row
         logical, intent(in) :: reuse

         logical :: estimates

         ! contact where u1 − u2 ≤ λ: for Newton-min exactly the vertices with the a-row
         call sys%contact_set(x, active)
         row%newton_it = k
         row%gmres_it = result%linear_iterations
         row%active = sys%global_count(active)
         row%active_changed = sys%global_count(active, other=previous)
         call watch%record(k, active, p%global, p%halo%owned, p%halo%comm)
         if (reuse) then
            call row%take_observations(result%history%rows(result%history%n))
            result%history%n = result%history%n - 1
         else if (present(observer)) then
            ! Algorithm 1 reads the estimators from the first step on: at the initial iterate
            ! (at 10^6 vertices, a fifth of the adaptive run's evaluations) no test needs them
            estimates = .not. adaptive
            if (adaptive .and. k > 0) estimates = check_evaluates(row)
            call observer%observe(x, row, estimates=estimates)
            if (adaptive .and. estimates) call inner%schedule%remember(row)
         end if
         row%wall_time = wall_time() - t0
         call result%history%append(row)
         if (options%verbose) call print_progress(row)
      end subroutine record

      !> Whether the adaptive method's check at the new iterate x evaluates the estimators
      !> (check_schedule_t; a check that does not keeps what it computed in `row`).
      logical function check_evaluates(row) result(estimates)
         type(history_row_t), intent(inout) :: row

         real(dp) :: eta_lin
         logical :: last

         estimates = inner%schedule%screen(observer, x, row, eta_lin)
         if (.not. estimates) return
         ! η_disc at least: the idle Krylov workspace and right-hand side make room for the
         ! evaluation's arrays (the next step allocates them again)
         call solver%workspace%free()
         deallocate (b)
         call return_freed_memory()
         estimates = inner%schedule%decide(observer, x, row, last, screened=eta_lin)
         ! a whole evaluation expected to end the run: the preconditioner's hierarchies make room
         ! for its algebraic flux too (the next solve, if any, builds them again)
         if (estimates .and. last .and. associated(inner%prec)) call inner%prec%release()
      end function check_evaluates
   end subroutine newton_solve
end module twomem_newton_solver
