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
!> unless told not to (`twomem_newton_fb_finish`). The loop reads as the method, each part a
!> method of the solve's state (`twomem_newton_state`): linearize, solve (`linear_step`), step
!> (`evaluate_trial`, then the line search in `take_step`), record (`record`, which asks the
!> observer and, in the adaptive method, lets `check_schedule_t` decide what a check computes)
!> and decide (`decide_stop`). What a solve is asked and answers is `twomem_newton_options`'s.
module twomem_newton_solver
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_history, only: history_row_t
   use twomem_newton_inner, only: newton_observer_t
   use twomem_newton_options, only: newton_options_t, newton_result_t, automatic_every, newton_running, &
      newton_iteration_limit
   use twomem_newton_state, only: newton_state_t
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
      type(newton_result_t), intent(out) :: result
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), intent(inout), target, optional :: observer
      type(multigrid_transfer_t), target, intent(inout), optional :: transfer
      integer, intent(in), optional :: level

      type(newton_state_t), target :: state
      type(history_row_t) :: row
      !> the relative residual and merit of the linear solve's iterate
      real(dp) :: trial_relative, trial_merit
      integer :: k

      call state%init(p, options, x0, err, observer, transfer, level)
      if (allocated(err)) return
      call state%start()
      k = 0
      do while (state%reason == newton_running)
         if (k == options%max_it) then
            state%reason = newton_iteration_limit
            exit
         end if
         k = k + 1
         call state%linearize()
         call state%linear_step(k, row, err)
         if (allocated(err)) return
         if (state%reason /= newton_running) exit
         call state%evaluate_trial(trial_relative, trial_merit)
         call state%take_step(k, trial_relative, trial_merit, row)
         call state%record(k, row, state%reuses_inner_row(row%step))
         call state%fb%step_moved(row%active_changed, row%active)
         call state%decide_stop(k, row)
      end do
      call state%finish(k, result)
   end subroutine newton_solve
end module twomem_newton_solver
