!> One case from a validated configuration to a result file: build the mesh hierarchy, the
!> problem data and the discrete problem on the finest level, run Newton, measure the exact
!> error when the solution is known, and write the result. `check` stops after the mesh. This
!> is the only place that knows the configuration and the numerical modules at once. Every
!> rank of a distributed run goes through it with its piece of the problem; rank 0 prints and
!> writes, and the ranks agree on every error before acting on it.
module twomem_app_run
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_ok, exit_not_converged, exit_bad_input, exit_io
   use twomem_base_system, only: make_directories, parent_directory, peak_memory_kib, process_id, remove_file, &
      is_directory, register_temporary, unregister_temporary, return_freed_memory
   use twomem_base_phases, only: phase_clock_t, phase_mesh, phase_assembly, phase_solve, phase_estimators, &
      phase_error, phase_output
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: method_direct, method_adaptive, c_function_fb, precond_mg, exact_bbbv, flux_rt1, &
      line_search_on, line_search_off, fb_finish_active_set, criteria_local, checks_predicted
   use omp_lib, only: omp_get_max_threads
   use twomem_base_version, only: twomem_version
   use twomem_linalg_umfpack, only: umfpack_library
   use twomem_base_text, only: fixed
   use twomem_input_config, only: config_t, config_echo
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_app_loads, only: make_data
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_solver, only: newton_options_t, newton_result_t, automatic_every
   use twomem_estimate_estimators, only: estimator_t, estimates_t, poincare_constant
   use twomem_app_observer, only: run_observer_t
   use twomem_app_mesh, only: build_hierarchy
   use twomem_app_levels, only: solve_levels, coarse_work_t
   use twomem_io_result, only: result_record_t, history_columns_t, output_choice_t, write_result, xdmf_path_for
   use twomem_newton_history, only: history_t
   use twomem_io_gather, only: gather_plan_t
   implicit none
   private

   public :: run_case, check_case

contains

   !> Validate input and mesh and print the resolved case; solve nothing. Collective.
   subroutine check_case(cfg, comm, err)
      type(config_t), intent(inout) :: cfg
      type(comm_t), intent(in) :: comm
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t) :: hierarchy

      call prepare(cfg, comm, err)
      if (allocated(err)) return
      call build_hierarchy(cfg, comm, hierarchy, err)
      if (allocated(err)) return
      if (comm%is_root()) write (output_unit, '(a)') 'check: input and mesh are valid; nothing solved'
   end subroutine check_case

   !> Collective; every rank returns the same exit code and error.
   subroutine run_case(cfg, comm, exit_code, err)
      type(config_t), intent(inout) :: cfg
      type(comm_t), intent(in) :: comm
      integer, intent(out) :: exit_code
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t), target :: hierarchy
      class(problem_data_t), allocatable, target :: data
      type(discrete_problem_t), target :: p
      type(newton_options_t) :: options
      type(newton_result_t) :: newton
      type(run_observer_t), target :: observer
      type(estimator_t), target :: estimator
      type(coarse_work_t) :: coarse
      type(result_record_t) :: rec
      type(output_choice_t) :: choice
      type(phase_clock_t) :: clock
      integer :: finest, n_whole
      logical :: need_estimates

      exit_code = exit_bad_input
      call clock%start(phase_mesh)
      call prepare(cfg, comm, err)
      if (allocated(err)) return
      ! the mesh first: bad input must not leave even an output directory behind
      call build_hierarchy(cfg, comm, hierarchy, err)
      if (allocated(err)) return
      if (comm%is_root()) call check_output_writable(trim(cfg%output%file), err)
      call comm%agree(err)
      if (allocated(err)) return
      finest = hierarchy%levels

      call clock%switch(phase_assembly)
      call make_data(cfg, comm, hierarchy, data, err)
      call comm%agree(err)
      if (allocated(err)) return
      call p%init(hierarchy%meshes(finest), data, err, comm)
      call comm%agree(err)
      if (allocated(err)) return
      n_whole = comm%sum(count(p%halo%owned))
      if (comm%is_root()) write (output_unit, '("problem: ",a,", ",i0," interior vertices, Newton system ",i0," x ",i0, &
           &", ",i0," MPI ranks x ",i0," OpenMP threads")') trim(data%name), n_whole, 3*n_whole, 3*n_whole, comm%size, &
         omp_get_max_threads()

      call newton_options_from(cfg, comm, options)
      call check_distributed(cfg, comm, options, err)
      if (allocated(err)) return
      ! estimator work only when the method or the output asks for it
      need_estimates = options%linear == method_adaptive .or. cfg%estimate%enabled
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

      call clock%switch(phase_solve)
      if (observer%with_error .or. observer%with_estimates) then
         call solve_levels(cfg, comm, hierarchy, data, p, options, clock, newton, coarse, err, observer)
      else
         call solve_levels(cfg, comm, hierarchy, data, p, options, clock, newton, coarse, err)
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

      call fill_record(cfg, comm, hierarchy, data, p, newton, coarse, need_estimates, observer, clock, rec, err)
      call comm%agree(err)
      if (allocated(err)) then
         exit_code = err%code
         return
      end if
      choice%fields = cfg%output%fields
      choice%estimators = cfg%output%estimators
      choice%history = cfg%output%history
      choice%xdmf = cfg%output%xdmf
      call clock%switch(phase_output)
      if (comm%is_root()) call write_result(trim(cfg%output%file), rec, choice, err, clock)
      call comm%agree(err)
      if (allocated(err)) then
         exit_code = exit_io
         return
      end if
      call clock%switch(0)
      if (comm%is_root()) call print_summary(cfg, data%has_exact(), need_estimates, choice, rec, clock)
      exit_code = merge(exit_ok, exit_not_converged, newton%converged)
   end subroutine run_case

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
   subroutine fill_record(cfg, comm, hierarchy, data, p, newton, coarse, need_estimates, observer, clock, rec, err)
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

      type(estimates_t) :: final
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
      end if
      rec%estimator_evaluations = observer%evaluations
      rec%estimator_time = observer%estimator_time
      rec%peak_memory_kib = int(comm%max(real(peak_memory_kib(), dp)), i8)
      rec%omp_threads = omp_get_max_threads()
      rec%mpi_ranks = comm%size
      rec%wall_time = clock%total()
   end subroutine fill_record

   !> The closing lines of a run: status, sizes, errors and estimators, where the time went.
   subroutine print_summary(cfg, has_exact, need_estimates, choice, rec, clock)
      type(config_t), intent(in) :: cfg
      logical, intent(in) :: has_exact, need_estimates
      type(output_choice_t), intent(in) :: choice
      type(result_record_t), intent(in) :: rec
      type(phase_clock_t), intent(in) :: clock

      character(len=64), allocatable :: lines(:)
      integer :: i

      write (output_unit, '("status: ",a)') rec%status
      write (output_unit, '("summary: ",i0," Newton steps, ",i0," vertices, ",i0," triangles, ",i0," MPI ranks x ",i0, &
           &" threads")') rec%newton_iterations, size(rec%vertices, 2), size(rec%triangles, 2), rec%mpi_ranks, &
         rec%omp_threads
      if (has_exact) write (output_unit, '("energy error: ",es12.5)') rec%energy_error_total
      if (need_estimates) write (output_unit, '("estimators: eta ",es12.5," (disc ",es10.3,", lin ",es10.3,", alg ",es10.3, &
           &"), ",i0," evaluations in ",a," s")') rec%eta_total, rec%eta_disc, rec%eta_lin, rec%eta_alg, &
         rec%estimator_evaluations, fixed(rec%estimator_time, 2)
      if (need_estimates .and. has_exact) write (output_unit, '("effectivity: ",a)') fixed(rec%effectivity, 4)
      call clock%table(lines)
      do i = 1, size(lines)
         write (output_unit, '("time: ",a)') trim(lines(i))
      end do
      if (rec%mpi_ranks > 1) then
         write (output_unit, '("wall time: ",a," s, peak memory: ",a," MiB (largest rank)")') fixed(clock%total(), 2), &
            fixed(real(rec%peak_memory_kib, dp)/1024, 1)
      else
         write (output_unit, '("wall time: ",a," s, peak memory: ",a," MiB")') fixed(clock%total(), 2), &
            fixed(real(rec%peak_memory_kib, dp)/1024, 1)
      end if
      write (output_unit, '("result: ",a)') trim(cfg%output%file)
      if (choice%xdmf .and. (choice%fields .or. has_exact)) &
         write (output_unit, '("paraview: ",a)') xdmf_path_for(trim(cfg%output%file))
   end subroutine print_summary

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

   !> Print the resolved input; refuse what this version cannot do yet.
   subroutine prepare(cfg, comm, err)
      type(config_t), intent(inout) :: cfg
      type(comm_t), intent(in) :: comm
      type(error_t), allocatable, intent(out) :: err

      if (cfg%problem%exact == exact_bbbv) then
         ! the paper's case fixes its data; show the values actually used
         cfg%problem%mu1 = 1.0_dp
         cfg%problem%mu2 = 1.0_dp
         cfg%problem%g = 0.05_dp
      end if
      if (.not. comm%is_root()) return
      write (output_unit, '(a)') 'twomem '//twomem_version//': case '''//trim(cfg%case_name)// &
         ''' from '//trim(cfg%source)
      write (output_unit, '(a)') config_echo(cfg)
      if (cfg%problem%exact == exact_bbbv) write (output_unit, '(a)') &
         'note: problem.exact=''bbbv'' sets mu1 = mu2 = 1, g = 0.05 and its own loads (f1, f2 unused)'
   end subroutine prepare

   !> Fail before any work when the result cannot be written: create the directory and a probe
   !> file beside the target, then remove the probe.
   subroutine check_output_writable(path, err)
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out) :: err

      type(error_t), allocatable :: ignored
      character(len=32) :: pid
      integer :: unit, ios
      character(len=256) :: msg

      if (is_directory(path) .or. path(len(path):) == '/') then
         call make_error(err, exit_io, path, 'the result file names a directory')
         return
      end if
      call make_directories(parent_directory(path), err)
      if (allocated(err)) then
         err%code = exit_io
         return
      end if
      write (pid, '(i0)') process_id()
      call register_temporary(path//'.probe-'//trim(pid))
      open (newunit=unit, file=path//'.probe-'//trim(pid), status='replace', action='write', &
            iostat=ios, iomsg=msg)
      if (ios /= 0) then
         call unregister_temporary()
         call make_error(err, exit_io, path, 'cannot write the result file: '//trim(msg))
         return
      end if
      close (unit, status='delete', iostat=ios)
      call remove_file(path//'.probe-'//trim(pid), ignored)
      call unregister_temporary()
   end subroutine check_output_writable

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
end module twomem_app_run
