!> One case from a validated configuration to a result file: build the mesh hierarchy and the
!> problem data, solve on the finest level (`twomem_app_solve`) or refine adaptively until the
!> estimate meets adapt.tol (`twomem_app_adapt`), and write the result. `check` stops after
!> the mesh. Every rank of a distributed run goes through it with its piece of the problem;
!> rank 0 prints and writes, and the ranks agree on every error before acting on it.
module twomem_app_run
   use, intrinsic :: iso_fortran_env, only: output_unit
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, exit_ok, exit_not_converged, exit_bad_input, exit_io
   use twomem_base_system, only: make_directories, parent_directory, process_id, remove_file, &
      is_directory, register_temporary, unregister_temporary
   use twomem_base_phases, only: phase_clock_t, phase_mesh, phase_assembly, phase_output
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: method_adaptive, exact_bbbv
   use twomem_base_version, only: twomem_version
   use twomem_base_text, only: fixed
   use twomem_input_config, only: config_t, config_echo
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_app_loads, only: make_data
   use twomem_app_mesh, only: build_hierarchy
   use twomem_app_solve, only: solve_mesh
   use twomem_app_adapt, only: adapt_mesh
   use twomem_io_result, only: result_record_t, output_choice_t, write_result, xdmf_path_for
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
      type(result_record_t) :: rec
      type(output_choice_t) :: choice
      type(phase_clock_t) :: clock
      logical :: need_estimates, converged, adaptive

      exit_code = exit_bad_input
      call clock%start(phase_mesh)
      call prepare(cfg, comm, err)
      if (allocated(err)) return
      adaptive = cfg%adapt%tol > 0.0_dp
      ! the mesh first: bad input must not leave even an output directory behind
      call build_hierarchy(cfg, comm, hierarchy, err)
      if (allocated(err)) return
      if (comm%is_root()) call check_output_writable(trim(cfg%output%file), err)
      call comm%agree(err)
      if (allocated(err)) return

      call clock%switch(phase_assembly)
      call make_data(cfg, comm, hierarchy, data, err)
      call comm%agree(err)
      if (allocated(err)) return
      if (adaptive) then
         call adapt_mesh(cfg, comm, hierarchy, data, clock, rec, converged, exit_code, err)
      else
         call solve_mesh(cfg, comm, hierarchy, data, clock, rec, converged, exit_code, err)
      end if
      if (allocated(err)) return
      need_estimates = cfg%newton%linear == method_adaptive .or. cfg%estimate%enabled .or. adaptive
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
      exit_code = merge(exit_ok, exit_not_converged, converged)
   end subroutine run_case




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

end module twomem_app_run
