!> The `twomem` executable: reads the command line, loads the case, runs or checks it, and is
!> the only place that prints errors and chooses the exit code (INTERFACE.md).
program twomem_main
   use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
   use twomem_base_errors, only: error_t, make_error, exit_ok, exit_bad_input
   use twomem_base_system, only: exit_program
   use twomem_base_version, only: twomem_version
   use twomem_input_config, only: config_t, string_t, load_config
   use twomem_app_run, only: run_case, check_case
   implicit none

   type(config_t) :: cfg
   type(error_t), allocatable :: err
   type(string_t), allocatable :: overrides(:)
   character(len=:), allocatable :: command, case_file
   integer :: n_args, i, exit_code

   n_args = command_argument_count()
   if (n_args == 0) then
      call make_error(err, exit_bad_input, 'twomem', 'missing command (see twomem --help)')
      call fail(err)
   end if
   command = argument(1)
   select case (command)
   case ('--help', '-h', 'help')
      call usage(output_unit)
      call exit_program(exit_ok)
   case ('--version', '-V')
      write (output_unit, '(a)') 'twomem '//twomem_version
      call exit_program(exit_ok)
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
         call check_case(cfg, err)
         if (allocated(err)) call fail(err)
         call exit_program(exit_ok)
      end if
      call run_case(cfg, exit_code, err)
      if (allocated(err)) call fail(err)
      call exit_program(exit_code)
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

   subroutine fail(err)
      type(error_t), intent(in) :: err

      flush (output_unit)
      write (error_unit, '(a)') 'twomem: error: '//err%message
      call exit_program(err%code)
   end subroutine fail

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
