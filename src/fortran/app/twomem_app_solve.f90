!> One solve on one mesh hierarchy, from a validated configuration and the problem data to the
!> result record: the discrete problem on the finest level, Newton (from the configured initial
!> guess, or from given nodal fields: an adaptive run's previous mesh), the final estimators, the
!> exact error when the solution is known, and everything gathered on rank 0. A plain run makes
!> one such solve (`twomem_app_run`); an adaptive run one per refinement step
!> (`twomem_app_adapt`). Every rank of a distributed run goes through it with its piece.
module twomem_app_solve
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_base_system, only: peak_memory_kib, return_freed_memory
   use twomem_base_phases, only: phase_clock_t, phase_solve, phase_estimators, phase_error, phase_output
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: method_direct, method_adaptive, c_function_fb, precond_mg, flux_rt1, &
      line_search_on, line_search_off, fb_finish_active_set, criteria_local, checks_predicted
   use omp_lib, only: omp_get_max_threads
   use twomem_base_version, only: twomem_version
   use twomem_linalg_umfpack, only: umfpack_library
   use twomem_input_config, only: config_t, config_echo
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_solver, only: newton_options_t, newton_result_t, automatic_every
   use twomem_estimate_estimators, only: estimator_t, estimates_t, poincare_constant
   use twomem_app_observer, only: run_observer_t
   use twomem_app_levels, only: solve_levels, solve_from, coarse_work_t, uses_multigrid
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_io_result, only: result_record_t, history_columns_t
   use twomem_newton_history, only: history_t
   use twomem_io_gather, only: gather_plan_t
   implicit none
   private

   public :: solve_mesh

contains

   !> Solve the problem on the finest mesh of `hierarchy` and fill `rec` (rank 0: the whole
   !> mesh). Without `nodal`, from the configured initial guess (nested iteration on the
   !> hierarchy); with it, from those nodal fields (nv, 3) of u1, u2, λ, and with
   !> `eta_disc_hint` a prediction of η_disc for the adaptive method's first check
   !> (newton_options_t). `converged`: Newton's. `exit_code` is what a failure means for the
   !> run. Collective; every rank returns the same error.
   subroutine solve_mesh(cfg, comm, hierarchy, data, clock, rec, converged, exit_code, err, nodal, indicators, &
                         eta_disc_hint)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), target, intent(in) :: hierarchy
      class(problem_data_t), target, intent(in) :: data
      type(phase_clock_t), intent(inout) :: clock
      type(result_record_t), intent(out) :: rec
      logical, intent(out) :: converged
      integer, intent(out) :: exit_code
      type(error_t), allocatable, intent(out) :: err
      real(dp), intent(in), optional :: nodal(:, :)
      !> η_disc,K of the final iterate, gathered (rank 0), for marking
      real(dp), allocatable, intent(out), optional :: indicators(:)
      real(dp), intent(in), optional :: eta_disc_hint

      type(discrete_problem_t), target :: p
      type(newton_options_t) :: options
      type(newton_result_t) :: newton
      type(run_observer_t), target :: observer
      type(estimator_t), target :: estimator
      !> the solve's multigrid transfers, kept through the final evaluation for its Riesz
      !> preconditioner (run_observer_t)
      type(multigrid_transfer_t), target :: transfer
      type(coarse_work_t) :: coarse
      integer :: finest, n_whole
      logical :: need_estimates

      exit_code = exit_bad_input
      converged = .false.
      finest = hierarchy%levels
      call p%init(hierarchy%meshes(finest), data, err, comm)
      call comm%agree(err)
      if (allocated(err)) return
      n_whole = comm%sum(count(p%halo%owned))
      if (comm%is_root()) write (output_unit, '("problem: ",a,", ",i0," interior vertices, Newton system ",i0," x ",i0, &
           &", ",i0," MPI ranks x ",i0," OpenMP threads")') trim(data%name), n_whole, 3*n_whole, 3*n_whole, comm%size, &
         omp_get_max_threads()

      call newton_options_from(cfg, comm, options)
      if (present(eta_disc_hint)) options%eta_disc_hint = eta_disc_hint
      call check_distributed(cfg, comm, options, err)
      if (allocated(err)) return
      ! estimator work only when the method, the output or the refinement asks for it
      need_estimates = options%linear == method_adaptive .or. cfg%estimate%enabled .or. present(indicators)
      if (need_estimates) then
         call clock%switch(phase_estimators)
         call estimator%init(hierarchy, data, merge(1, 0, cfg%estimate%flux == flux_rt1), cfg%estimate%alg_levels, &
                             poincare_constant(cfg%mesh%domain, hierarchy%meshes(finest)%diameter), err, comm, &
                             bound=cfg%estimate%bound)
         if (allocated(err)) then
            exit_code = err%code
            return
         end if
      end if
      call observer%init(hierarchy, data, p, estimator, with_error=data%has_exact() .and. cfg%output%history, &
                         with_estimates=options%linear == method_adaptive .or. &
                                        (cfg%estimate%enabled .and. cfg%output%history), &
                         gamma_alg=cfg%estimate%gamma_alg, gamma_lin=cfg%newton%gamma_lin, &
                         local_criteria=options%local_criteria)
      if (uses_multigrid(options)) call observer%share_transfer(transfer)

      call clock%switch(phase_solve)
      if (present(nodal)) then
         if (observer%with_error .or. observer%with_estimates) then
            call solve_from(comm, hierarchy, p, options, nodal, transfer, newton, err, observer)
         else
            call solve_from(comm, hierarchy, p, options, nodal, transfer, newton, err)
         end if
      else if (observer%with_error .or. observer%with_estimates) then
         call solve_levels(cfg, comm, hierarchy, data, p, options, clock, transfer, newton, coarse, err, observer)
      else
         call solve_levels(cfg, comm, hierarchy, data, p, options, clock, transfer, newton, coarse, err)
      end if
      ! what the observer measured inside the Newton loop is not solver time
      call clock%charge(phase_estimators, observer%estimator_time)
      call clock%charge(phase_error, observer%error_time)
      if (.not. allocated(err) .and. allocated(observer%err)) call move_alloc(observer%err, err)
      call comm%agree(err)
      if (allocated(err)) then
         exit_code = err%code
         return
      end if
      ! the solver's memory, free now, would otherwise stay beside the estimators' per-triangle
      ! fields, which it does not fit as it lies; the other fields of the result fit in it, and
      ! pages given back would be zeroed again for them (0.3 GB at 4.5·10^6 vertices)
      if (need_estimates) call return_freed_memory()

      call fill_record(cfg, comm, hierarchy, data, p, newton, coarse, need_estimates, observer, clock, rec, err, &
                       indicators)
      call comm%agree(err)
      if (allocated(err)) then
         exit_code = err%code
         return
      end if
      converged = newton%converged
   end subroutine solve_mesh

   !> What a distributed run cannot do (yet): refuse it before any work.
   subroutine check_distributed(cfg, comm, options, err)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(newton_options_t), intent(in) :: options
      type(error_t), allocatable, intent(out) :: err

      if (comm%size == 1) return
      if (options%precond /= precond_mg .and. options%linear /= method_direct) then
         call make_error(err, exit_bad_input, 'gmres.precond', '''ilu0'', ''jacobi'' and ''none'' act on one '// &
                         'rank''s matrix: on several MPI ranks use ''mg''')
      end if
   end subroutine check_distributed

   !> Everything the result file holds, from the run's objects (gathered on rank 0): mesh,
   !> fields, the final estimators (reusing the last evaluation when it saw the final iterate)
   !> and the exact error. Collective.
   subroutine fill_record(cfg, comm, hierarchy, data, p, newton, coarse, need_estimates, observer, clock, rec, err, &
                          indicators)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      !> its stiffness matrix goes once the estimators are final
      type(discrete_problem_t), intent(inout) :: p
      type(newton_result_t), intent(in) :: newton
      type(coarse_work_t), intent(in) :: coarse
      logical, intent(in) :: need_estimates
      type(run_observer_t), intent(inout) :: observer
      type(phase_clock_t), intent(inout) :: clock
      type(result_record_t), intent(out) :: rec
      type(error_t), allocatable, intent(out) :: err
      !> the discretization estimator's element indicators η_disc,K of the whole mesh, gathered
      !> on rank 0 (the refinement's marking)
      real(dp), allocatable, intent(out), optional :: indicators(:)

      type(estimates_t) :: final
      real(dp) :: ignored
      type(gather_plan_t) :: plan
      real(dp), allocatable :: u1(:), u2(:), energy(:)
      real(dp) :: nan

      nan = ieee_value(1.0_dp, ieee_quiet_nan)
      ! in this order: the exact error (small arrays) while the memory the solver left is at
      ! hand; the estimators' per-triangle fields, which need the evaluation's workspaces (the
      ! fluxes), and those workspaces given back; only then the gathered result (at 10^6
      ! vertices the workspaces and the gathered arrays together made the run's peak)
      associate (mesh => hierarchy%meshes(hierarchy%levels))
         call plan%init(comm, mesh)
         u1 = p%to_nodal(newton%x(1:p%n), data%g)
         u2 = p%to_nodal(newton%x(p%n + 1:2*p%n), 0.0_dp)
         rec%energy_error_total = nan
         if (data%has_exact()) then
            call clock%switch(phase_error)
            if (.not. observer%exact_energy%ready(mesh)) call observer%exact_energy%init(mesh, data)
            energy = observer%exact_energy%per_element(mesh, u1, u2)
            ! no later iterate asks for it: room for the estimators' fields
            call observer%exact_energy%free()
            rec%energy_error = plan%cells(energy)
            rec%energy_error_total = sqrt(comm%sum(sum(energy(1:mesh%nt_owned)**2)))
            deallocate (energy)
         end if
         if (need_estimates) then
            call clock%switch(phase_estimators)
            call observer%evaluate_last(newton%x)
            if (allocated(observer%err)) then
               call move_alloc(observer%err, err)
               return
            end if
            ! the stiffness served the residuals of the evaluations: room for the fields
            call p%free_stiffness()
            call observer%estimate(final)
            call observer%free_workspaces()
            call return_freed_memory()
         end if
         ! the gathered fields are the result's preparation (docs/output.md: `output`)
         call clock%switch(phase_output)
         call plan%mesh_arrays(mesh, rec%vertices, rec%triangles)
         rec%u1 = plan%nodal(u1)
         rec%u2 = plan%nodal(u2)
         rec%lambda = plan%nodal(p%to_nodal(newton%x(2*p%n + 1:), 0.0_dp))
      end associate
      rec%version = twomem_version
      rec%umfpack = umfpack_library()
      rec%input_text = config_echo(cfg)
      rec%status = newton%status
      rec%levels = hierarchy%levels
      call history_columns(newton%history, rec%history)
      rec%newton_iterations = newton%iterations
      rec%gmres_iterations = newton%linear_iterations
      rec%newton_iterations_coarse = coarse%newton_iterations
      rec%gmres_iterations_coarse = coarse%gmres_iterations
      rec%eta_total = nan
      rec%eta_disc = nan
      rec%eta_lin = nan
      rec%eta_alg = nan
      rec%eta_alg_remainder = nan
      rec%effectivity = nan
      if (need_estimates) then
         rec%eta_total = final%total
         rec%eta_disc = final%disc
         rec%eta_lin = final%lin
         rec%eta_alg = final%alg
         rec%eta_alg_remainder = final%alg_remainder
         if (data%has_exact()) rec%effectivity = final%total/rec%energy_error_total
         if (cfg%output%estimators) call estimator_fields(final, plan, rec)
         if (present(indicators)) then
            call final%field('eta_disc', indicators, ignored)
            indicators = plan%cells(indicators)
         end if
      end if
      rec%estimator_evaluations = observer%evaluations
      rec%estimator_time = observer%estimator_time
      rec%peak_memory_kib = int(comm%max(real(peak_memory_kib(), dp)), i8)
      rec%omp_threads = omp_get_max_threads()
      rec%mpi_ranks = comm%size
      rec%wall_time = clock%total()
   end subroutine fill_record

   subroutine newton_options_from(cfg, comm, options)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(newton_options_t), intent(out) :: options

      options%cfun = cfg%newton%cfun
      options%linear = cfg%newton%linear
      options%max_it = cfg%newton%max_it
      options%tol = cfg%newton%tol
      select case (cfg%newton%line_search)
      case (line_search_on)
         options%line_search = .true.
      case (line_search_off)
         options%line_search = .false.
      case default
         options%line_search = options%cfun == c_function_fb
      end select
      options%fb_active_set = cfg%newton%fb_finish == fb_finish_active_set
      options%forcing = cfg%gmres%forcing
      options%precond = cfg%gmres%precond
      options%gmres%restart = cfg%gmres%restart
      options%gmres%max_it = cfg%gmres%max_it
      options%gmres%rtol = cfg%gmres%rtol
      options%gmres%observe_every = cfg%estimate%every
      if (options%gmres%observe_every == 0) &
         options%gmres%observe_every = automatic_every(options%linear, options%cfun, options%precond, &
                                                         options%fb_active_set)
      options%gamma_lin = cfg%newton%gamma_lin
      options%gamma_alg = cfg%estimate%gamma_alg
      options%local_criteria = cfg%estimate%criteria == criteria_local
      options%predicted_checks = cfg%estimate%checks == checks_predicted
      options%verbose = comm%is_root()
   end subroutine newton_options_from

   !> The `/estimators` fields of docs/output.md from one evaluation, gathered on rank 0 in the
   !> whole mesh's order. Collective.
   subroutine estimator_fields(est, plan, rec)
      type(estimates_t), intent(in) :: est
      type(gather_plan_t), intent(in) :: plan
      type(result_record_t), intent(inout) :: rec

      character(len=*), parameter :: names(10) = [character(len=16) :: 'eta_total', 'eta_disc', 'eta_lin', &
                                                   'eta_alg', 'eta_F', 'eta_osc', 'eta_C', 'eta_nonc1', &
                                                   'eta_nonc2', 'eta_nonc3']
      real(dp), allocatable :: values(:)
      integer :: i

      rec%estimator_names = names
      allocate (rec%estimator_totals(size(names)))
      do i = 1, size(names)
         call est%field(trim(names(i)), values, rec%estimator_totals(i))
         values = plan%cells(values)
         if (i == 1) allocate (rec%estimators(size(values), size(names)))
         rec%estimators(:, i) = values
      end do
   end subroutine estimator_fields

   !> The solver's history rows as the result file's columns.
   subroutine history_columns(history, columns)
      type(history_t), intent(in) :: history
      type(history_columns_t), intent(out) :: columns

      associate (r => history%rows(1:history%n))
         columns%newton_it = int(r%newton_it, ip)
         columns%gmres_it = int(r%gmres_it, ip)
         columns%eta_disc = r%eta_disc
         columns%eta_lin = r%eta_lin
         columns%eta_alg = r%eta_alg
         columns%eta_total = r%eta_total
         columns%energy_error = r%energy_error
         columns%lin_residual = r%lin_residual
         columns%alg_residual = r%alg_residual
         columns%active = int(r%active, ip)
         columns%active_changed = int(r%active_changed, ip)
         columns%step = r%step
         columns%inner = int(merge(1, 0, r%inner), ip)
         columns%wall_time = r%wall_time
      end associate
   end subroutine history_columns
end module twomem_app_solve
