!> The fuzz driver: feeds mutated inputs to the real parsers in process, many per second.
!>
!>   twomem_fuzz gmsh|namelist|override          fuzz one parser (settings: fuzz_harness)
!>   twomem_fuzz gmsh|namelist|override DIR      write the inputs to DIR instead, unparsed
!>
!> Exit status 0 when every input kept the contract, 1 when one did not, 2 on a usage error; a
!> crash or a hang is the process dying or ctest's timeout.
program twomem_fuzz
   implicit none

   integer :: status

   ! the work is done in a subroutine, whose allocatables are freed on return: LeakSanitizer
   ! then sees no leak unless the parsers leak
   call main(status)
   if (status == 1) error stop 1
   if (status == 2) error stop 2

contains

   subroutine main(status)
      use, intrinsic :: iso_fortran_env, only: output_unit
      use fuzz_harness, only: settings_t, fuzz_target_t, load_settings, run_fuzz, write_samples, &
         env_text
      use fuzz_gmsh, only: gmsh_target_t
      use fuzz_config, only: namelist_target_t, override_target_t
      integer, intent(out) :: status

      type(settings_t) :: s
      class(fuzz_target_t), allocatable :: target
      character(len=:), allocatable :: name, dir, data, source
      logical :: ok, passed

      status = 2
      if (command_argument_count() < 1 .or. command_argument_count() > 2) then
         write (output_unit, '(a)') 'usage: twomem_fuzz gmsh|namelist|override [DIR]'
         return
      end if
      name = argument(1)
      call load_settings(s, ok)
      if (.not. ok) return
      data = env_text('TWOMEM_TEST_DATA')
      source = env_text('TWOMEM_SOURCE_DIR')
      if (len(data) == 0 .or. len(source) == 0) then
         write (output_unit, '(a)') 'twomem_fuzz: TWOMEM_TEST_DATA and TWOMEM_SOURCE_DIR must '// &
            'be set (run through ctest)'
         return
      end if

      select case (name)
      case ('gmsh')
         allocate (gmsh_target_t :: target)
         select type (target)
         type is (gmsh_target_t)
            call target%init(data)
         end select
      case ('namelist')
         allocate (namelist_target_t :: target)
         select type (target)
         type is (namelist_target_t)
            call target%init(source)
         end select
      case ('override')
         allocate (override_target_t :: target)
         select type (target)
         type is (override_target_t)
            call target%init(source, s%tmp)
         end select
      case default
         write (output_unit, '(a)') 'twomem_fuzz: unknown target "'//name// &
            '" (gmsh, namelist, override)'
         return
      end select

      if (command_argument_count() == 2) then
         dir = argument(2)
         call write_samples(target, s, dir)
         status = 0
         return
      end if
      call run_fuzz(target, s, passed)
      status = merge(0, 1, passed)
   end subroutine main

   function argument(i) result(arg)
      integer, intent(in) :: i
      character(len=:), allocatable :: arg

      integer :: length

      call get_command_argument(i, length=length)
      allocate (character(len=length) :: arg)
      if (length > 0) call get_command_argument(i, arg)
   end function argument
end program twomem_fuzz
