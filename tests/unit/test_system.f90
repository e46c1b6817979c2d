!> Tests of the operating-system layer: directory trees, atomic rename, removal, path parts, and
!> the C library's decimal conversion (the bits of a Fortran read).
module test_system
   use twomem_base_kinds, only: dp, i8
   use twomem_base_errors, only: exit_io
   use twomem_base_system, only: make_directories, parent_directory, base_name, rename_file, &
                                 remove_file, file_exists, process_id, peak_memory_kib, decimal_value
   use twomem_base_timer, only: wall_time
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   implicit none
   private

   public :: collect_system

contains

   subroutine collect_system(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('make_directories', test_make_directories), &
               new_unittest('make_directories_under_file', test_mkdir_under_file), &
               new_unittest('rename_and_remove', test_rename), &
               new_unittest('path_parts', test_path_parts), &
               new_unittest('process_facts', test_process), &
               new_unittest('decimal_value', test_decimal_value)]
   end subroutine collect_system

   !> `TWOMEM_TEST_TMP/system/`: only ctest says where scratch files may go.
   function scratch_dir(err) result(dir)
      type(error_t), allocatable, intent(out) :: err
      character(len=:), allocatable :: dir

      character(len=1024) :: root
      integer :: length, status

      dir = ''
      call get_environment_variable('TWOMEM_TEST_TMP', root, length, status)
      call check(err, status == 0 .and. length > 0, 'TWOMEM_TEST_TMP is not set (run through ctest)')
      if (allocated(err)) return
      dir = root(1:length)//'/system/'
   end function scratch_dir

   subroutine touch(path, text, err)
      character(len=*), intent(in) :: path, text
      type(error_t), allocatable, intent(out) :: err

      integer :: unit, ios

      open (newunit=unit, file=path, status='replace', action='write', iostat=ios)
      call check(err, ios == 0, 'cannot create '//path)
      if (allocated(err)) return
      write (unit, '(a)') text
      close (unit)
   end subroutine touch

   subroutine test_make_directories(err)
      type(error_t), allocatable, intent(out) :: err
      character(len=:), allocatable :: dir

      dir = scratch_dir(err)
      if (allocated(err)) return
      call make_directories(dir//'a/b//c/d/', err)
      if (allocated(err)) return
      call check(err, file_exists(dir//'a/b/c/d'), 'nested directories created')
      if (allocated(err)) return
      ! an existing tree is fine
      call make_directories(dir//'a/b/c', err)
   end subroutine test_make_directories

   subroutine test_mkdir_under_file(err)
      type(error_t), allocatable, intent(out) :: err
      type(error_t), allocatable :: got
      character(len=:), allocatable :: dir

      dir = scratch_dir(err)
      if (.not. allocated(err)) call make_directories(dir, err)
      if (.not. allocated(err)) call touch(dir//'plain', 'x', err)
      if (allocated(err)) return
      call make_directories(dir//'plain/sub/dir', got)
      call check(err, allocated(got), 'directory under a file rejected')
      if (.not. allocated(got)) return
      call check(err, got%code == exit_io, 'I/O error code')
      call check(err, index(got%message, dir//'plain/sub/dir: ') == 1, 'names the path: '//got%message)
      call check(err, index(got%message, 'Not a directory') > 0, 'gives the cause: '//got%message)
      call make_directories(dir//'plain', got)
      call check(err, allocated(got), 'an existing file is not a directory')
   end subroutine test_mkdir_under_file

   subroutine test_rename(err)
      type(error_t), allocatable, intent(out) :: err
      type(error_t), allocatable :: got
      character(len=:), allocatable :: dir, from, to
      character(len=16) :: line
      integer :: unit, ios

      dir = scratch_dir(err)
      if (.not. allocated(err)) call make_directories(dir, err)
      if (allocated(err)) return
      from = dir//'from.txt'
      to = dir//'to.txt'
      call touch(to, 'old', err)
      if (.not. allocated(err)) call touch(from, 'new', err)
      if (.not. allocated(err)) call rename_file(from, to, err)
      if (allocated(err)) return
      call check(err, .not. file_exists(from), 'source gone')
      open (newunit=unit, file=to, status='old', action='read', iostat=ios)
      call check(err, ios == 0, 'target exists')
      if (allocated(err)) return
      read (unit, '(a)', iostat=ios) line
      close (unit)
      call check(err, ios == 0 .and. line == 'new', 'target replaced')

      call rename_file(from, to, got)
      call check(err, allocated(got), 'missing source reported')
      if (allocated(got)) call check(err, got%code == exit_io .and. index(got%message, from//': ') == 1 &
                                     .and. index(got%message, 'No such file') > 0, got%message)

      call remove_file(to, err)
      if (allocated(err)) return
      call check(err, .not. file_exists(to), 'removed')
      ! removing what is not there is fine
      call remove_file(to, err)
   end subroutine test_rename

   subroutine test_path_parts(err)
      type(error_t), allocatable, intent(out) :: err

      call check(err, parent_directory('results/a.h5') == 'results', 'parent of relative')
      call check(err, parent_directory('a.h5') == '.', 'parent of bare name')
      call check(err, parent_directory('/a.h5') == '/', 'parent in root')
      call check(err, parent_directory('/x//y/a.h5') == '/x//y', 'parent of absolute')
      call check(err, parent_directory('x//a.h5') == 'x', 'doubled slash')
      call check(err, parent_directory('x/y/') == 'x', 'trailing slash')
      call check(err, parent_directory('/') == '/', 'parent of root')
      call check(err, parent_directory('') == '.', 'parent of nothing')
      call check(err, base_name('results/a.h5') == 'a.h5', 'base of relative')
      call check(err, base_name('a.h5') == 'a.h5', 'base of bare name')
      call check(err, base_name('x/y/') == 'y', 'base with trailing slash')
      call check(err, base_name('/') == '/', 'base of root')
   end subroutine test_path_parts

   subroutine test_process(err)
      type(error_t), allocatable, intent(out) :: err
      integer(i8) :: kib
      real(dp) :: t0, t1

      kib = peak_memory_kib()
      t0 = wall_time()
      t1 = wall_time()
      call check(err, process_id() > 0, 'process id')
      call check(err, kib > 0_i8, 'peak memory')
      call check(err, t1 >= t0 .and. t0 > 0.0_dp, 'wall time')
   end subroutine test_process

   !> decimal_value gives the bits of a list-directed read of the same token, whatever its form
   !> (signs, no integer or no fraction digits, d exponents, subnormals, many digits), and
   !> declines a token it cannot convert whole or one too long for its buffer.
   subroutine test_decimal_value(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=*), parameter :: tokens(12) = [character(len=40) :: '0.1', '-1.2345678901234567e-3', &
         '3.0d-2', '+2.5E+2', '.5', '5.', '1e-310', '123456789012345678', '0.30000000000000004', &
         '-0.0', '6.02214076D23', '4.9406564584124654e-324']
      character(len=40) :: token
      real(dp) :: value, expected
      integer :: k, ios
      logical :: ok

      do k = 1, size(tokens)
         token = tokens(k)
         read (token, *, iostat=ios) expected
         call check(err, ios == 0, 'the test token '//trim(tokens(k))//' reads')
         if (allocated(err)) return
         ok = decimal_value(trim(tokens(k)), value)
         call check(err, ok .and. transfer(value, 1_i8) == transfer(expected, 1_i8), &
                    trim(tokens(k))//': the bits of a Fortran read')
         if (allocated(err)) return
      end do
      call check(err, .not. decimal_value('1.5x', value), 'a token with a trailing character is declined')
      if (allocated(err)) return
      call check(err, .not. decimal_value('0.'//repeat('1', 70), value), 'a 72-character token is declined')
   end subroutine test_decimal_value
end module test_system
