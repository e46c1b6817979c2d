!> What a run computes about each recorded iterate besides residuals: the a posteriori
!> estimators (for the adaptive method's stopping tests and for the history) and, when the exact
!> solution is known, the energy error. It counts and times the estimator evaluations, so that
!> their cost can be reported next to the solver's. When the estimators' algebraic flux is the
!> one-level construction, it owns the preconditioner of that flux's Riesz problem: one V-cycle
!> for the finest stiffness on the multigrid transfers that nested iteration and the Newton
!> preconditioner use (the solve's own, shared through `share_transfer`, since building them
!> again, aggregation and its Galerkin products, costs about a twentieth of a run on a large
!> single mesh; transfers of its own when the solve has none), built at an evaluation that needs
!> it and freed with the evaluation's workspaces (`free_workspaces`, `drop_partial`) and when
!> evaluations end.
module twomem_app_observer
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_timer, only: wall_time
   use twomem_base_system, only: return_freed_memory
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_error, only: exact_energy_t
   use twomem_newton_history, only: history_row_t
   use twomem_newton_inner, only: newton_observer_t
   use twomem_estimate_estimators, only: estimator_t, estimates_t
   use twomem_linalg_multigrid, only: multigrid_transfer_t, multigrid_options_t
   use twomem_linalg_mg_preconditioner, only: mg_preconditioner_t
   use twomem_app_transfers, only: hierarchy_transfer
   implicit none
   private

   public :: run_observer_t

   type, extends(newton_observer_t) :: run_observer_t
      type(mesh_hierarchy_t), pointer :: hierarchy => null()
      class(problem_data_t), pointer :: data => null()
      type(discrete_problem_t), pointer :: p => null()
      type(estimator_t), pointer :: estimator => null()
      logical :: with_error = .false., with_estimates = .false.
      real(dp) :: gamma_alg = 0.3_dp, gamma_lin = 0.3_dp
      !> the local stopping criteria (64) read per-triangle values at every evaluation; the
      !> global ones only totals, and the output the final iterate's fields
      logical :: local_criteria = .false.
      integer :: evaluations = 0
      !> the exact solution's part of the energy error, integrated at the first error
      type(exact_energy_t) :: exact_energy
      !> time spent in estimator evaluations and in exact-error evaluations
      real(dp) :: estimator_time = 0.0_dp, error_time = 0.0_dp
      !> the last evaluation, which the final result reuses when Newton ended at its iterate;
      !> `held`: the estimator's workspaces hold that evaluation (they also hold its iterate,
      !> `estimator_t%holds`, so no copy of it is kept here)
      type(estimates_t) :: last
      logical :: held = .false.
      !> set by `expect_whole` for the next `discretization_estimate`
      logical :: whole_expected = .false.
      !> the first failure of an evaluation (its estimators stay NaN, which no stopping test
      !> accepts); the run reports it after Newton
      type(error_t), allocatable :: err
      !> the one-level algebraic flux's preconditioner and its transfers (see the module header):
      !> the solve's, or `own` ones
      type(multigrid_transfer_t), pointer :: solve_transfer => null()
      type(multigrid_transfer_t), allocatable :: own_transfer
      type(mg_preconditioner_t), allocatable :: riesz
   contains
      procedure :: init
      procedure :: share_transfer
      procedure :: observe
      procedure :: linearization_estimate
      procedure :: discretization_estimate
      procedure :: evaluate_last
      procedure :: estimate
      procedure :: free_workspaces
      procedure :: drop_partial
      procedure :: expect_whole
      procedure :: free_riesz
      procedure, private :: refresh
      procedure, private :: riesz_preconditioner
   end type run_observer_t

contains

   !> The observer of a run on `hierarchy` (its finest level is p's mesh) with `data`: the exact
   !> error when `with_error`, the estimators of `estimator` when `with_estimates`, and the
   !> local criteria (64) with γ_alg, γ_lin when `local_criteria`. All four objects must outlive
   !> the observer.
   subroutine init(self, hierarchy, data, p, estimator, with_error, with_estimates, gamma_alg, gamma_lin, &
                   local_criteria)
      class(run_observer_t), intent(inout) :: self
      type(mesh_hierarchy_t), target, intent(in) :: hierarchy
      class(problem_data_t), target, intent(in) :: data
      type(discrete_problem_t), target, intent(in) :: p
      type(estimator_t), target, intent(inout) :: estimator
      logical, intent(in) :: with_error, with_estimates
      real(dp), intent(in) :: gamma_alg, gamma_lin
      logical, intent(in) :: local_criteria

      self%hierarchy => hierarchy
      self%data => data
      self%p => p
      self%estimator => estimator
      self%with_error = with_error
      self%with_estimates = with_estimates
      self%gamma_alg = gamma_alg
      self%gamma_lin = gamma_lin
      self%local_criteria = local_criteria
   end subroutine init

   !> The Riesz preconditioner is to use the solve's multigrid transfers `transfer` (built by
   !> the solve before its first evaluation), which must outlive the observer's evaluations.
   subroutine share_transfer(self, transfer)
      class(run_observer_t), intent(inout) :: self
      type(multigrid_transfer_t), target, intent(in) :: transfer

      self%solve_transfer => transfer
   end subroutine share_transfer

   subroutine observe(self, x, row, estimates)
      class(run_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      type(history_row_t), intent(inout) :: row
      logical, intent(in) :: estimates

      real(dp) :: t0

      if (estimates .and. self%with_estimates .and. .not. allocated(self%err)) then
         call self%refresh(x)
         if (.not. allocated(self%err)) then
            row%eta_disc = self%last%disc
            row%eta_lin = self%last%lin
            row%eta_alg = self%last%alg
            row%eta_total = self%last%total
            if (self%local_criteria) &
               call self%last%local_criteria(self%hierarchy%meshes(self%hierarchy%levels), self%gamma_alg, &
                                             self%gamma_lin, row%local_alg_ok, row%local_lin_ok, self%p%halo%comm)
         end if
      end if
      if (self%with_error) then
         t0 = wall_time()
         associate (mesh => self%hierarchy%meshes(self%hierarchy%levels))
            if (.not. self%exact_energy%ready(mesh)) call self%exact_energy%init(mesh, self%data)
            ! this rank's own triangles, summed over the ranks
            row%energy_error = sqrt(self%p%halo%comm%sum(self%exact_energy%squared_total(mesh, self%p, x)))
         end associate
         self%error_time = self%error_time + (wall_time() - t0)
      end if
   end subroutine observe

   !> η_lin alone at x (estimator_t%linearization_estimate: no flux), timed with the
   !> evaluations but not counted as one; NaN when the run computes no estimators or one failed.
   function linearization_estimate(self, x) result(eta_lin)
      class(run_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp) :: eta_lin

      real(dp) :: t0

      eta_lin = ieee_value(1.0_dp, ieee_quiet_nan)
      if (.not. self%with_estimates .or. allocated(self%err)) return
      t0 = wall_time()
      eta_lin = self%estimator%linearization_estimate(self%hierarchy, self%p, x)
      self%estimator_time = self%estimator_time + (wall_time() - t0)
   end function linearization_estimate

   !> η_disc at x without the algebraic flux (estimator_t%evaluate with algebraic = .false.):
   !> an evaluation, counted and timed, which a later `observe` of the same x completes; NaN
   !> when the run computes no estimators or the evaluation failed.
   function discretization_estimate(self, x) result(eta_disc)
      class(run_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp) :: eta_disc

      eta_disc = ieee_value(1.0_dp, ieee_quiet_nan)
      if (.not. self%with_estimates .or. allocated(self%err)) return
      call self%refresh(x, algebraic=self%whole_expected)
      self%whole_expected = .false.
      if (.not. allocated(self%err)) eta_disc = self%last%disc
   end function discretization_estimate

   !> The next `discretization_estimate` is likely to be completed: with the one-level algebraic
   !> flux, whose patch systems are the discretization flux's, it computes both in one pass
   !> (twomem_estimate_disc_flux), which saves the second pass's operators and factorizations;
   !> with a coarse solve there is nothing to share, and the algebraic flux waits for the
   !> completion. Returns whether the next evaluation will be whole.
   logical function expect_whole(self)
      class(run_observer_t), intent(inout) :: self

      self%whole_expected = .false.
      if (associated(self%estimator)) self%whole_expected = self%estimator%alg%one_level
      expect_whole = self%whole_expected
   end function expect_whole

   !> The run's last evaluation, at x: one timed evaluation, or the previous one if it saw this
   !> very x. What only evaluations need then goes (estimator_t%end_evaluations), and none
   !> follows: `estimate` hands its estimators over.
   subroutine evaluate_last(self, x)
      class(run_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)

      call self%refresh(x, fields=.true.)
      call self%free_riesz()
      if (allocated(self%err)) return
      call self%estimator%end_evaluations()
      call return_freed_memory()
   end subroutine evaluate_last

   !> Every estimator of `evaluate_last`'s iterate with its per-triangle fields (its element pass
   !> run again for the fields it left out), handed over: the observer keeps the global values
   !> only.
   subroutine estimate(self, est)
      class(run_observer_t), intent(inout) :: self
      type(estimates_t), intent(out) :: est

      real(dp) :: t0

      if (allocated(self%err)) return
      if (.not. self%last%has_fields()) then
         t0 = wall_time()
         call self%estimator%element_fields(self%hierarchy, self%data, self%last)
         self%estimator_time = self%estimator_time + (wall_time() - t0)
      end if
      call self%last%hand_over(est)
   end subroutine estimate

   !> After the run's last evaluation: the estimator's workspaces go (`last` keeps its values),
   !> and the next check evaluates afresh.
   subroutine free_workspaces(self)
      class(run_observer_t), intent(inout) :: self

      if (associated(self%estimator)) call self%estimator%free_workspaces()
      ! the Riesz problem's V-cycle too: the Newton steps until the next evaluation need the room
      call self%free_riesz()
      self%held = .false.
   end subroutine free_workspaces

   !> The η_disc just computed will not be completed (the next check sees another iterate): the
   !> workspaces go, back to the kernel, until the next evaluation, so that the Newton steps in
   !> between (their Krylov bases) do not meet them. The price is the kernel's zeroing of the
   !> pages when the next evaluation makes them again, which is small against the evaluation
   !> itself (docs/performance.md, *Memory at the peak*).
   subroutine drop_partial(self)
      class(run_observer_t), intent(inout) :: self

      call self%free_workspaces()
      call return_freed_memory()
   end subroutine drop_partial

   !> self%last at x, evaluated into the arrays of the previous evaluation (or new ones after
   !> `drop_partial` or `free_workspaces`), unless it already is at x (on every rank: the
   !> evaluation is collective, so the ranks decide together); completed with the algebraic
   !> flux if it was left out and `algebraic` (default) asks for it. Per-triangle fields when
   !> the local criteria need them, or `fields`.
   subroutine refresh(self, x, fields, algebraic)
      class(run_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      logical, intent(in), optional :: fields, algebraic

      real(dp) :: t0
      logical :: with_fields, with_alg, same

      with_alg = .true.
      if (present(algebraic)) with_alg = algebraic
      with_fields = self%local_criteria
      if (present(fields)) with_fields = with_fields .or. fields
      same = .not. self%p%halo%comm%any_true(.not. (self%held .and. self%estimator%holds(self%p, x)))
      if (same .and. (self%last%complete .or. .not. with_alg)) return
      t0 = wall_time()
      if (with_alg .and. self%estimator%alg%one_level) then
         call self%riesz_preconditioner(self%err)
         if (allocated(self%err)) then
            self%held = .false.
            return
         end if
      end if
      if (same) then
         if (allocated(self%riesz)) then
            call self%estimator%complete(self%hierarchy, self%data, self%last, self%err, with_fields, self%p, self%riesz)
         else
            call self%estimator%complete(self%hierarchy, self%data, self%last, self%err, with_fields, self%p)
         end if
      else
         if (allocated(self%riesz) .and. with_alg) then
            call self%estimator%evaluate(self%hierarchy, self%data, self%p, x, self%last, self%err, fields=with_fields, &
                                         algebraic=with_alg, precond=self%riesz)
         else
            call self%estimator%evaluate(self%hierarchy, self%data, self%p, x, self%last, self%err, fields=with_fields, &
                                         algebraic=with_alg)
         end if
         self%evaluations = self%evaluations + 1
      end if
      self%estimator_time = self%estimator_time + (wall_time() - t0)
      self%held = .not. allocated(self%err)
   end subroutine refresh

   !> The one-level algebraic flux's preconditioner, built if not yet: one V-cycle for the finest
   !> stiffness on the transfers the solves use (twomem_app_transfers: the hierarchy's levels
   !> that have unknowns, with algebraic levels below a mesh too large for a direct solve, so
   !> that a single mesh, an adapted one for instance, is not factorized whole at every
   !> evaluation's first use). Collective.
   subroutine riesz_preconditioner(self, err)
      class(run_observer_t), target, intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      type(multigrid_options_t) :: options
      type(multigrid_transfer_t), pointer :: transfer

      if (associated(self%solve_transfer)) then
         transfer => self%solve_transfer
      else
         if (.not. allocated(self%own_transfer)) then
            allocate (self%own_transfer)
            associate (comm => self%p%halo%comm, hierarchy => self%hierarchy)
               call hierarchy_transfer(comm, hierarchy, hierarchy%first_with_unknowns(comm), self%p, .true., &
                                       self%own_transfer, err)
            end associate
            if (allocated(err)) then
               call self%free_riesz()
               return
            end if
         end if
         transfer => self%own_transfer
      end if
      if (allocated(self%riesz)) then
         ! the Newton preconditioner drops the shared restrictions while an evaluation runs
         ! (elimination_preconditioner_t%release); transposed again, they have the same bits
         call transfer%restore_restrictions()
         return
      end if
      allocate (self%riesz)
      call self%riesz%init(self%p%stiffness, transfer, transfer%levels, options, err)
      if (allocated(err)) call self%free_riesz()
   end subroutine riesz_preconditioner

   !> The one-level algebraic flux's preconditioner and its own transfers go (after the last
   !> evaluation); the solve's stay the solve's.
   subroutine free_riesz(self)
      class(run_observer_t), intent(inout) :: self

      if (allocated(self%riesz)) then
         call self%riesz%release()
         deallocate (self%riesz)
      end if
      if (allocated(self%own_transfer)) deallocate (self%own_transfer)
   end subroutine free_riesz
end module twomem_app_observer
