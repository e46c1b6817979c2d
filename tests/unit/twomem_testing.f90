!> A small test harness in the test-drive manner: a suite is a list of named procedures, each
!> returning an error object when an expectation fails. One tester executable runs one suite
!> per ctest entry, so a failure names its suite and its test.
module twomem_testing
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   implicit none
   private

   public :: unittest_t, test_interface, new_unittest, run_suite
   public :: check, check_close, error_t

   abstract interface
      subroutine test_interface(err)
         import :: error_t
         type(error_t), allocatable, intent(out) :: err
      end subroutine test_interface
   end interface

   type :: unittest_t
      character(len=:), allocatable :: name
      procedure(test_interface), pointer, nopass :: run => null()
   end type unittest_t

contains

   function new_unittest(name, run) result(test)
      character(len=*), intent(in) :: name
      procedure(test_interface) :: run
      type(unittest_t) :: test

      test%name = name
      test%run => run
   end function new_unittest

   !> Record a failure unless `condition` holds; keeps the first failure of a test.
   subroutine check(err, condition, message)
      type(error_t), allocatable, intent(inout) :: err
      logical, intent(in) :: condition
      character(len=*), intent(in) :: message

      if (allocated(err)) return
      if (.not. condition) call make_error(err, exit_bad_input, '', message)
   end subroutine check

   !> |actual - expected| <= atol + rtol |expected|
   subroutine check_close(err, actual, expected, rtol, atol, what)
      type(error_t), allocatable, intent(inout) :: err
      real(dp), intent(in) :: actual, expected, rtol, atol
      character(len=*), intent(in) :: what

      character(len=256) :: msg

      if (allocated(err)) return
      if (.not. (abs(actual - expected) <= atol + rtol*abs(expected))) then
         write (msg, '(a,": got ",es23.15," expected ",es23.15," (diff ",es10.3,")")') &
            what, actual, expected, abs(actual - expected)
         call make_error(err, exit_bad_input, '', trim(msg))
      end if
   end subroutine check_close

   !> Run every test of a suite, report each, return the number of failures.
   integer function run_suite(suite, tests) result(n_failed)
      character(len=*), intent(in) :: suite
      type(unittest_t), intent(in) :: tests(:)

      type(error_t), allocatable :: err
      integer :: i

      n_failed = 0
      do i = 1, size(tests)
         call tests(i)%run(err)
         if (allocated(err)) then
            n_failed = n_failed + 1
            write (*, '(a)') '  FAIL '//suite//'/'//tests(i)%name//': '//err%message
            deallocate (err)
         else
            write (*, '(a)') '  ok   '//suite//'/'//tests(i)%name
         end if
      end do
      write (*, '(i0," passed, ",i0," failed")') size(tests) - n_failed, n_failed
   end function run_suite
end module twomem_testing
