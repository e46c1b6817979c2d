!> The `twomem` executable: reads the command line, loads the case, runs or checks it, and is
!> the only place that prints errors and chooses the exit code (docs/input.md). It starts MPI
!> and makes the one communicator everything distributed is passed (a run without `mpirun` is
!> one rank); every rank parses the same input and agrees on every error, rank 0 prints, and
!> all ranks end together with the same exit code.
program twomem_main
   use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
   use twomem_base_errors, only: error_t, make_error, exit_ok, exit_bad_input
   use twomem_base_system, only: exit_program, install_guards, keep_freed_memory
   use twomem_base_version, only: twomem_version
   use twomem_linalg_umfpack, only: umfpack_library
   use twomem_input_config, only: config_t, string_t, load_config
   use twomem_app_run, only: run_case, check_case
   use twomem_base_comm, only: comm_t, comm_start, comm_stop, mpi_library
   implicit none

   type(comm_t) :: comm
   type(config_t) :: cfg
   type(error_t), allocatable :: err
   type(string_t), allocatable :: overrides(:)
   character(len=:), allocatable :: command, case_file
   integer :: n_args, i, exit_code

   call keep_freed_memory()
   call comm_start(comm)
   ! after MPI's start, so that these handlers, not the MPI library's, see SIGTERM and SIGINT
   call install_guards(comm%is_root())
   n_args = command_argument_count()
   if (n_args == 0) then
      call make_error(err, exit_bad_input, 'twomem', 'missing command (see twomem --help)')
      call fail(err)
   end if
   command = argument(1)
   select case (command)
   case ('--help', '-h', 'help')
      if (comm%is_root()) call usage(output_unit)
      call finish(exit_ok)
   case ('--version', '-V')
      if (comm%is_root()) write (output_unit, '(a)') 'twomem '//twomem_version, 'MPI: '//mpi_library(), &
         'UMFPACK: '//umfpack_library()
      call finish(exit_ok)
   case ('run', 'check')
      if (n_args < 2) then
         call make_error(err, exit_bad_input, 'twomem '//command, 'missing CASE.nml (see twomem --help)')
         call fail(err)
      end if
      case_file = argument(2)
      allocate (overrides(n_args - 2))
      do i = 3, n_args
         overrides(i - 2)%s = argument(i)
      end do
      call load_config(case_file, overrides, cfg, err)
      if (allocated(err)) call fail(err)
      if (command == 'check') then
         call check_case(cfg, comm, err)
         call comm%agree(err)
         if (allocated(err)) call fail(err)
         call finish(exit_ok)
      end if
      call run_case(cfg, comm, exit_code, err)
      call comm%agree(err)
      if (allocated(err)) call fail(err)
      call finish(exit_code)
   case default
      call make_error(err, exit_bad_input, 'twomem', 'unknown command '''//command// &
                      ''' (expected run, check, --help or --version)')
      call fail(err)
   end select

contains

   function argument(i) result(arg)
      integer, intent(in) :: i
      character(len=:), allocatable :: arg

      integer :: length

      call get_command_argument(i, length=length)
      allocate (character(len=length) :: arg)
      if (length > 0) call get_command_argument(i, arg)
   end function argument

   !> The one error line (rank 0 prints it), then the error's exit code on every rank.
   subroutine fail(err)
      type(error_t), intent(in) :: err

      flush (output_unit)
      if (comm%is_root()) write (error_unit, '(a)') 'twomem: error: '//err%message
      call finish(err%code)
   end subroutine fail

   !> End MPI, then the process with `code` (the same on every rank).
   subroutine finish(code)
      integer, intent(in) :: code

      call comm_stop(comm)
      call exit_program(code)
   end subroutine finish

   subroutine usage(unit)
      integer, intent(in) :: unit

      write (unit, '(a)') &
         'usage: twomem run CASE.nml [GROUP.KEY=VALUE ...]   solve a case, write its result', &
         '       twomem check CASE.nml [GROUP.KEY=VALUE ...] validate input and mesh, solve nothing', &
         '       twomem --help | --version', &
         '', &
         'Overrides apply after the file, in the namelist''s own syntax, e.g.', &
         '  twomem run input/default.nml mesh.levels=5 newton.cfun=min output.file=out/a.h5', &
         '', &
         'Exit codes: 0 solved, 1 not converged (result written, status says why),', &
         '            2 bad input or usage (nothing written), 3 I/O or environment failure.', &
         'Input keys and defaults: docs/input.md; result layout: docs/output.md.'
   end subroutine usage
end program twomem_main
