!> What happens every ν GMRES iterations inside a Newton step: the current GMRES iterate gets a
!> history row (its linearization and algebraic residuals, and whatever the run's observer
!> computes: estimators, exact errors), and GMRES is stopped by the inexact method's test. With
!> the paper's forcing that is ‖R_alg‖/‖B‖ ≤ ‖R_lin(x)‖/‖[F; 0]‖; in the adaptive method it is
!> η_alg ≤ γ_alg max(η_disc, η_lin) (paper eq. (63a)) or its local form (64a). The Newton-level
!> counterparts (63b)/(64b) live here too, so both of the paper's criteria sit in one place.
!> One refinement of the paper's forcing (gmres.forcing = 'finish', the default; 'paper' keeps the
!> paper's test as published): when the GMRES iterate takes the Newton step's branch of the min
!> at every vertex, R_lin and the algebraic residual are the same vector, and stopping there
!> would only hand the rest of this linear solve to the next Newton step (one more
!> linearization, preconditioner update and GMRES start): GMRES goes on to newton.tol instead.
!> Which checks of the adaptive method evaluate the estimators is `check_schedule_t`'s choice
!> (estimate.checks): at 10^6 vertices an evaluation costs as much as three or four Newton
!> steps, and far from the stop the Newton test cannot hold. A skipped check is stopped by the
!> inexact method's forcing above, and its row leaves the estimators NaN. A whole evaluation
!> that the schedule expects to end the run first releases the preconditioner's memory (the
!> multigrid hierarchies): the evaluation's algebraic flux needs about as much, and the peak
!> of the run is where both would meet. Should GMRES go on, its next application rebuilds them.
!> That evaluation is put off to the end of GMRES's cycle (`gmres_observer_t%pending`): GMRES
!> ends the cycle at the same iterate and frees its Krylov basis first, the other large block in
!> memory then; only if the algebraic test fails does the solve go on, from a restart. So is a
!> check where the inexact test stops GMRES anyway and η_lin asks for η_disc (the first check
!> of the run, whose discretization flux would otherwise meet the basis, and a check that may
!> end the run): whatever it computes, GMRES ends there unless an evaluation says otherwise.
module twomem_newton_inner
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_is_finite, ieee_is_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_base_timer, only: wall_time
   use twomem_base_system, only: return_freed_memory
   use twomem_linalg_gmres, only: gmres_observer_t
   use twomem_linalg_operators, only: preconditioner_t
   use twomem_base_options, only: c_function_min, method_adaptive, forcing_fixed, forcing_finish
   use twomem_newton_cfun, only: cfun_eval
   use twomem_newton_residual, only: nonlinear_residual_t
   use twomem_newton_history, only: history_t, history_row_t, not_computed
   use twomem_newton_options, only: newton_options_t
   implicit none
   private

   public :: newton_observer_t, inner_observer_t, check_schedule_t, alg_criterion, lin_criterion

   !> Extension point: fill the error/estimator columns of a history row for iterate x; the
   !> estimator columns only when `estimates` (a row whose estimators no stopping test reads,
   !> such as the adaptive method's initial iterate, is spared their cost). An observer that
   !> can compute η_lin alone, much more cheaply than a whole evaluation, says so through
   !> `linearization_estimate`, and one that can compute η_disc without the algebraic part
   !> through `discretization_estimate` (NaN: it cannot, and the adaptive method evaluates
   !> everything). `drop_partial` tells it that the last `discretization_estimate` will not be
   !> completed: what it kept for that may go. `expect_whole` announces that the next
   !> `discretization_estimate` is likely to be completed (the Newton test held at the last η_disc
   !> known): one whose algebraic part shares work with η_disc may compute both at once, and
   !> answers whether it will.
   type, abstract :: newton_observer_t
   contains
      procedure(observe_interface), deferred :: observe
      procedure :: linearization_estimate => no_partial_estimate
      procedure :: discretization_estimate => no_partial_estimate
      procedure :: drop_partial => nothing_to_drop
      procedure :: expect_whole => never_whole
   end type newton_observer_t

   abstract interface
      subroutine observe_interface(self, x, row, estimates)
         import :: newton_observer_t, history_row_t, dp
         class(newton_observer_t), intent(inout) :: self
         real(dp), intent(in) :: x(:)
         type(history_row_t), intent(inout) :: row
         logical, intent(in) :: estimates
      end subroutine observe_interface
   end interface

   !> Whether a check of the adaptive method evaluates the estimators. With `predict` (the
   !> default, estimate.checks = 'predicted') the Newton test η_lin ≤ γ_lin η_disc decides, in
   !> three stages of growing cost: η_lin alone (a pass over the triangles, no flux); if the
   !> test can hold with the last known η_disc (which moves by a few percent between Newton
   !> steps while η_lin moves by orders of magnitude), η_disc at this iterate (the
   !> discretization flux, about half of an evaluation); and if the test holds with it, the
   !> rest (the algebraic flux, η_alg, the bound). A check that stops before the last stage
   !> keeps in its row what it computed. The first check has no η_disc to go by unless the
   !> caller predicts one (`newton_options_t%eta_disc_hint`: a step of adaptive refinement
   !> scales the previous mesh's η_disc, which η_disc follows to within a few percent), and a
   !> check after an evaluation that failed has none: they start at the second stage. Judging by
   !> the global test also serves the local criteria, which imply it. Only the first stage
   !> predicts: a wrong skip costs one more Newton step, and no stop is ever decided without a
   !> whole evaluation.
   type :: check_schedule_t
      logical :: predict = .false.
      real(dp) :: gamma_lin = 0.3_dp
      !> η_disc of the last evaluation, or the caller's prediction before the first (none, or
      !> the last evaluation failed: −1)
      real(dp) :: eta_disc = -1
   contains
      procedure :: decide
      procedure :: screen
      procedure :: wanted
      procedure :: remember
   end type check_schedule_t

   !> What a check put off until GMRES has freed its Krylov basis has still to do: the decision
   !> after η_lin (stages 2 and 3 of `check_schedule_t`), or the whole evaluation.
   integer, parameter :: put_off_none = 0, put_off_decision = 1, put_off_whole = 2

   !> GMRES's observer inside the Newton steps of one solve: configured once by `init`, told of
   !> each GMRES solve by `start_solve`.
   type, extends(gmres_observer_t) :: inner_observer_t
      !> the adaptive method's choice of the checks that evaluate the estimators (the driver's
      !> Newton-level checks share it)
      type(check_schedule_t) :: schedule
      !> the running solve's preconditioner: an evaluation expected to end the run takes its
      !> memory (`release`; applied again, it rebuilds)
      class(preconditioner_t), pointer :: prec => null()
      !> the relative residual of the last iterate observed, while c, da, db still hold the run's
      !> C-function there (NaN otherwise): when GMRES stops at that iterate, the driver takes
      !> them instead of evaluating the same residual again
      real(dp) :: last_relative = 0.0_dp
      type(nonlinear_residual_t), pointer, private :: residual => null()
      type(history_t), pointer, private :: history => null()
      class(newton_observer_t), pointer, private :: user => null()
      logical, private :: paper_forcing = .true., adaptive = .false., local_criteria = .false.
      !> finish the linear solve once the iterate takes the step's branches (gmres.forcing 'finish')
      logical, private :: finish = .false.
      real(dp), private :: gamma_alg = 0.3_dp, newton_tol = 0.0_dp
      !> the C-function of the Newton step's Jacobian (min also in FB's active-set steps)
      integer, private :: linearized = c_function_min
      integer, private :: newton_it = 0, gmres_before = 0
      real(dp), private :: b_norm = 1.0_dp, t0 = 0.0_dp
      !> a check put off until GMRES has freed its basis (put_off_*), the row of its check so far
      !> (the residuals, and η_lin, η_disc when known) and the η_lin that asked for η_disc
      integer, private :: put_off = put_off_none
      type(history_row_t), private :: pending_row
      real(dp), private :: pending_eta_lin = 0
      !> work: C and its Jacobian at the GMRES iterate (the Newton driver's arrays for them,
      !> which it does not read while GMRES runs)
      real(dp), pointer, contiguous, private :: c(:) => null(), da(:) => null(), db(:) => null()
   contains
      procedure :: init => inner_init
      procedure :: start_solve
      procedure :: observe => observe_gmres
      procedure :: pending => check_pending
   end type inner_observer_t

contains

   !> Record the GMRES iterate x and decide whether GMRES stops here.
   subroutine observe_gmres(self, iteration, x, residual_norm, stop)
      class(inner_observer_t), intent(inout) :: self
      integer, intent(in) :: iteration
      real(dp), intent(in) :: x(:)
      real(dp), intent(in) :: residual_norm
      logical, intent(out) :: stop

      type(history_row_t) :: row
      real(dp) :: eta_lin
      !> forced: the inexact test stops GMRES at this iterate, as far as it has been asked (tested)
      logical :: estimates, last, forced, tested

      stop = .false.
      tested = .false.
      eta_lin = ieee_value(1.0_dp, ieee_quiet_nan)
      if (self%put_off /= put_off_none) then
         ! GMRES has ended its cycle at the same iterate (bit for bit) and freed its basis: the
         ! row is the one of the check, whose inexact test stopped GMRES if it was put off
         ! before the decision
         row = self%pending_row
         forced = self%put_off == put_off_decision
         tested = forced
         if (forced) then
            ! the basis's memory goes back before the flux's arrays are made, which it cannot hold
            call return_freed_memory()
            estimates = self%schedule%decide(self%user, x, row, last, screened=self%pending_eta_lin, prec=self%prec)
         else
            estimates = .true.
            last = .true.
         end if
         self%put_off = put_off_none
         ! an evaluation expected to end the run takes the hierarchies' memory too
         if (estimates .and. last .and. associated(self%prec)) call self%prec%release()
      else
         row = new_row(self, iteration, x, residual_norm)
         estimates = .true.
         forced = .false.
         if (self%adaptive .and. associated(self%user)) then
            if (self%schedule%predict) then
               forced = forcing_stop(self, x, row)
               tested = .true.
            end if
            if (forced) then
               ! GMRES ends here unless an evaluation's algebraic test says otherwise: η_disc,
               ! if η_lin asks for it, waits for the basis to go (an observer without partial
               ! estimates, NaN, evaluates everything here, as at any other check)
               estimates = self%schedule%screen(self%user, x, row, eta_lin)
               if (estimates .and. .not. ieee_is_nan(eta_lin)) then
                  call put_off(self, put_off_decision, row, eta_lin)
                  return
               end if
            else
               estimates = self%schedule%decide(self%user, x, row, last)
               if (estimates .and. last) then
                  call put_off(self, put_off_whole, row, eta_lin)
                  return
               end if
            end if
         end if
      end if
      if (associated(self%user)) call self%user%observe(x, row, estimates=estimates)
      row%wall_time = wall_time() - self%t0
      call self%history%append(row)
      if (self%adaptive .and. estimates) then
         call self%schedule%remember(row)
         stop = alg_criterion(row, self%gamma_alg, self%local_criteria)
      else if (tested) then
         stop = forced
      else
         stop = forcing_stop(self, x, row)
      end if
   end subroutine observe_gmres

   !> The row of GMRES iterate x: its residuals and contact set, nothing observed yet.
   function new_row(self, iteration, x, residual_norm) result(row)
      type(inner_observer_t), intent(inout) :: self
      integer, intent(in) :: iteration
      real(dp), intent(in) :: x(:), residual_norm
      type(history_row_t) :: row

      row = not_computed()
      call self%residual%relative(x, row%lin_residual, self%c, self%da, self%db)
      self%last_relative = row%lin_residual
      row%alg_residual = residual_norm/self%b_norm
      row%newton_it = self%newton_it
      row%gmres_it = self%gmres_before + iteration
      row%active = self%residual%sys%contact_count(x)
      row%inner = .true.
      row%step = ieee_value(1.0_dp, ieee_quiet_nan)
      row%active_changed = -1
   end function new_row

   !> The inexact method's test at GMRES iterate x, whose residuals `row` holds.
   logical function forcing_stop(self, x, row) result(stop)
      type(inner_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      type(history_row_t), intent(in) :: row

      ! For Newton-min, once GMRES's iterate has the Jacobian's contact set, B − A x and
      ! R_lin(x) are the same vector computed two ways: the slack keeps round-off from
      ! deciding the tie. At that tie the linearization residual is all algebraic, and
      ! stopping would leave the next Newton step nothing to do but go on with this very
      ! solve: GMRES goes on to newton.tol instead.
      stop = (self%paper_forcing .or. self%adaptive) .and. row%alg_residual <= row%lin_residual*(1 + 1.0e-8_dp)
      if (stop .and. self%finish .and. row%lin_residual > self%newton_tol .and. self%linearized == c_function_min) &
         stop = .not. same_branches(self, x)
   end function forcing_stop

   !> Answer `pending` until GMRES calls again with its basis freed.
   subroutine put_off(self, what, row, eta_lin)
      type(inner_observer_t), intent(inout) :: self
      integer, intent(in) :: what
      type(history_row_t), intent(in) :: row
      real(dp), intent(in) :: eta_lin

      self%put_off = what
      self%pending_row = row
      self%pending_eta_lin = eta_lin
   end subroutine put_off

   !> Whether the check at iterate x evaluates the estimators (collective: the estimators are
   !> the same on every rank); a check that does not keeps η_lin, and η_disc if it computed it,
   !> in its row. `last`: a whole evaluation that the Newton test predicts to be the last, before
   !> which the caller makes room (the preconditioner's hierarchies, the Krylov basis).
   !> `screened`: η_lin of x, which `screen` found worth going on with. `prec`: present when the
   !> Krylov basis is freed, so that the check may take the algebraic flux at once
   !> (`expect_whole`): the running solve's preconditioner (or a null pointer), released before
   !> such an evaluation.
   logical function decide(self, user, x, row, last, screened, prec) result(evaluates)
      class(check_schedule_t), intent(inout) :: self
      class(newton_observer_t), intent(inout) :: user
      real(dp), intent(in) :: x(:)
      type(history_row_t), intent(inout) :: row
      logical, intent(out) :: last
      real(dp), intent(in), optional :: screened
      class(preconditioner_t), pointer, intent(in), optional :: prec

      real(dp) :: eta_lin, eta_disc

      evaluates = .true.
      last = .false.
      if (.not. self%predict) return
      if (present(screened)) then
         eta_lin = screened
      else if (.not. self%screen(user, x, row, eta_lin)) then
         evaluates = .false.
         return
      end if
      if (ieee_is_nan(eta_lin)) return
      ! η_lin passed the Newton test against the last η_disc, which changes little between
      ! Newton steps: this check will most likely evaluate everything; if the observer does so
      ! at once, the preconditioner makes room as for an evaluation expected to end the run
      if (self%eta_disc >= 0 .and. present(prec)) then
         if (user%expect_whole()) then
            if (associated(prec)) call prec%release()
         end if
      end if
      eta_disc = user%discretization_estimate(x)
      if (ieee_is_nan(eta_disc)) return
      self%eta_disc = eta_disc
      if (eta_lin > self%gamma_lin*eta_disc) then
         row%eta_lin = eta_lin
         row%eta_disc = eta_disc
         evaluates = .false.
         ! the next check sees another iterate
         call user%drop_partial()
      else
         ! the Newton test holds here: unless the algebraic test fails, this evaluation ends the
         ! run, and its algebraic flux need not meet the solver's memory
         last = .true.
      end if
   end function decide

   !> The first stage of a check at iterate x: η_lin (`eta_lin`), and whether the check goes on
   !> (NaN: the observer cannot tell η_lin alone, or checks are not predicted, and the check
   !> evaluates everything). One that does not keeps η_lin in its row.
   logical function screen(self, user, x, row, eta_lin) result(go_on)
      class(check_schedule_t), intent(in) :: self
      class(newton_observer_t), intent(inout) :: user
      real(dp), intent(in) :: x(:)
      type(history_row_t), intent(inout) :: row
      real(dp), intent(out) :: eta_lin

      go_on = .true.
      eta_lin = ieee_value(1.0_dp, ieee_quiet_nan)
      if (.not. self%predict) return
      eta_lin = user%linearization_estimate(x)
      go_on = self%wanted(eta_lin)
      if (.not. go_on) row%eta_lin = eta_lin
   end function screen

   !> A check waits for GMRES to free its Krylov basis (see the type).
   logical function check_pending(self) result(pending)
      class(inner_observer_t), intent(in) :: self

      pending = self%put_off /= put_off_none
   end function check_pending

   !> The observer of the GMRES solves of a Newton solve with `options`: it evaluates the GMRES
   !> iterates' residuals with `residual` into c, da, db (the driver's arrays for C and its
   !> Jacobian, which the driver does not read while GMRES runs), appends their rows to
   !> `history` with times from t0, asks the run's observer `user`, if any, and may release
   !> `prec`, the solves' preconditioner, before an evaluation expected to end the run. All of
   !> them must outlive the observer.
   subroutine inner_init(self, options, residual, c, da, db, history, t0, user, prec)
      class(inner_observer_t), intent(out) :: self
      type(newton_options_t), intent(in) :: options
      type(nonlinear_residual_t), target, intent(inout) :: residual
      real(dp), target, contiguous, intent(inout) :: c(:), da(:), db(:)
      type(history_t), target, intent(inout) :: history
      real(dp), intent(in) :: t0
      class(newton_observer_t), target, intent(inout), optional :: user
      class(preconditioner_t), target, intent(inout), optional :: prec

      self%residual => residual
      self%c => c
      self%da => da
      self%db => db
      self%history => history
      if (present(user)) self%user => user
      self%adaptive = options%linear == method_adaptive
      self%paper_forcing = options%forcing /= forcing_fixed .and. .not. self%adaptive
      self%finish = options%forcing == forcing_finish
      self%local_criteria = options%local_criteria
      self%gamma_alg = options%gamma_alg
      self%schedule%predict = options%predicted_checks
      self%schedule%gamma_lin = options%gamma_lin
      self%schedule%eta_disc = merge(options%eta_disc_hint, -1.0_dp, options%eta_disc_hint > 0)
      self%newton_tol = options%tol
      self%t0 = t0
      if (present(prec)) self%prec => prec
   end subroutine inner_init

   !> A GMRES solve begins in Newton step `newton_it`, which linearized C-function `linearized`,
   !> after `gmres_before` GMRES iterations of the Newton solve, for a right-hand side of norm
   !> `b_norm`. A check put off by a solve that did not come back to it (it failed) is forgotten,
   !> and so is the residual of the last step's iterates.
   subroutine start_solve(self, newton_it, linearized, gmres_before, b_norm)
      class(inner_observer_t), intent(inout) :: self
      integer, intent(in) :: newton_it, linearized, gmres_before
      real(dp), intent(in) :: b_norm

      self%newton_it = newton_it
      self%put_off = put_off_none
      self%last_relative = ieee_value(1.0_dp, ieee_quiet_nan)
      self%linearized = linearized
      self%gmres_before = gmres_before
      self%b_norm = b_norm
   end subroutine start_solve

   !> Whether an iterate whose η_lin is `eta_lin` is worth an evaluation: the Newton test can
   !> hold with the last η_disc (always, without one or without a prediction).
   pure logical function wanted(self, eta_lin)
      class(check_schedule_t), intent(in) :: self
      real(dp), intent(in) :: eta_lin

      wanted = .true.
      if (.not. self%predict .or. self%eta_disc < 0 .or. ieee_is_nan(eta_lin)) return
      wanted = eta_lin <= self%gamma_lin*self%eta_disc
   end function wanted

   !> Keep an evaluated row's η_disc for the next checks; a failed evaluation (NaN) forgets the
   !> last one, so that the next check evaluates.
   subroutine remember(self, row)
      class(check_schedule_t), intent(inout) :: self
      type(history_row_t), intent(in) :: row

      self%eta_disc = -1
      if (ieee_is_finite(row%eta_disc)) self%eta_disc = row%eta_disc
   end subroutine remember

   !> The default keeps nothing for a completion and prepares nothing for one.
   subroutine nothing_to_drop(self)
      class(newton_observer_t), intent(inout) :: self
   end subroutine nothing_to_drop

   !> The default: nothing computed at once.
   logical function never_whole(self)
      class(newton_observer_t), intent(inout) :: self

      never_whole = .false.
   end function never_whole

   !> The default: no part of the estimators without a whole evaluation.
   function no_partial_estimate(self, x) result(eta)
      class(newton_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp) :: eta

      eta = ieee_value(1.0_dp, ieee_quiet_nan)
   end function no_partial_estimate

   !> Whether the min's Jacobian at the GMRES iterate x is the one the Newton step linearized
   !> (the same branch of the min at every vertex), on every rank. An exact comparison: the
   !> decision does not depend on round-off. With Newton-min, `relative` has left that Jacobian
   !> in self%da, self%db; in an active-set step of Fischer–Burmeister it is computed here (the
   !> FB residual of the iterate then tends to zero with the algebraic one too).
   logical function same_branches(self, x) result(same)
      type(inner_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)

      associate (sys => self%residual%sys)
         if (self%residual%cfun /= c_function_min) then
            call cfun_eval(c_function_min, x, self%c, self%da, self%db)
            self%last_relative = ieee_value(1.0_dp, ieee_quiet_nan)
         end if
         same = .not. sys%jacobian_differs(self%da, self%db)
      end associate
   end function same_branches

   !> The paper's GMRES stop (63a), η_alg ≤ γ_alg max(η_disc, η_lin), or its local form (64a).
   pure logical function alg_criterion(row, gamma_alg, local) result(ok)
      type(history_row_t), intent(in) :: row
      real(dp), intent(in) :: gamma_alg
      logical, intent(in) :: local

      if (local) then
         ok = row%local_alg_ok
      else if (ieee_is_nan(row%eta_alg) .or. ieee_is_nan(row%eta_disc) .or. ieee_is_nan(row%eta_lin)) then
         ! not evaluated (and no comparison with a NaN, which traps in the debug build)
         ok = .false.
      else
         ok = row%eta_alg <= gamma_alg*max(row%eta_disc, row%eta_lin)
      end if
   end function alg_criterion

   !> The paper's Newton stop (63b), η_lin ≤ γ_lin η_disc, or its local form (64b).
   pure logical function lin_criterion(row, gamma_lin, local) result(ok)
      type(history_row_t), intent(in) :: row
      real(dp), intent(in) :: gamma_lin
      logical, intent(in) :: local

      if (local) then
         ok = row%local_lin_ok
      else if (ieee_is_nan(row%eta_disc) .or. ieee_is_nan(row%eta_lin)) then
         ok = .false.
      else
         ok = row%eta_lin <= gamma_lin*row%eta_disc
      end if
   end function lin_criterion
end module twomem_newton_inner
