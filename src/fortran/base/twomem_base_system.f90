!> What twomem asks of the operating system: directory trees for output files, the atomic rename
!> that makes a result file appear only when complete, clean-up of leftovers, the process id (for
!> unique temporary names), the peak memory for the run summary, the memory the process may
!> still use, and the guards of src/c/twomem_guard.c (SIGTERM/SIGINT and failed allocations end
!> the run with one line after removing the registered temporary file). The only Fortran that talks
!> to src/c/twomem_system.c. It also ends the program with a chosen exit code, which Fortran 2008
!> cannot do quietly (`stop` takes only a constant, and prints it); only the main program calls it; failures come back as `exit_io` errors naming the path and the
!> system's reason (strerror). Path arithmetic (`parent_directory`, `base_name`) is plain Fortran.
!> `decimal_value` converts a checked decimal token with the C library's strtod, which a Fortran
!> internal read calls too, at a fraction of the read's cost (a mesh file's coordinates).
module twomem_base_system
   use, intrinsic :: iso_c_binding, only: c_char, c_int, c_int64_t, c_size_t, c_null_char, c_double
   use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
   use twomem_base_kinds, only: dp, i8
   use twomem_base_errors, only: error_t, make_error, exit_io
   implicit none
   private

   public :: make_directories, parent_directory, base_name, rename_file, remove_file, file_exists, is_directory
   public :: process_id, peak_memory_kib, keep_freed_memory, return_freed_memory, c_text, exit_program
   public :: memory_allowed_bytes, install_guards, register_temporary, unregister_temporary, decimal_value

   integer, parameter :: msg_len = 1024

   interface
      integer(c_int) function c_make_directories(path, msg, cap) bind(C, name='twomem_sys_make_directories')
         import :: c_char, c_int, c_size_t
         character(kind=c_char), intent(in) :: path(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_make_directories

      integer(c_int) function c_rename(from, to, msg, cap) bind(C, name='twomem_sys_rename')
         import :: c_char, c_int, c_size_t
         character(kind=c_char), intent(in) :: from(*), to(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_rename

      integer(c_int) function c_remove(path, msg, cap) bind(C, name='twomem_sys_remove')
         import :: c_char, c_int, c_size_t
         character(kind=c_char), intent(in) :: path(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_remove

      integer(c_int) function c_exists(path) bind(C, name='twomem_sys_exists')
         import :: c_char, c_int
         character(kind=c_char), intent(in) :: path(*)
      end function c_exists

      subroutine c_exit(code) bind(C, name='twomem_sys_exit')
         import :: c_int
         integer(c_int), value :: code
      end subroutine c_exit

      integer(c_int) function c_is_directory(path) bind(C, name='twomem_sys_is_directory')
         import :: c_int, c_char
         character(kind=c_char), intent(in) :: path(*)
      end function c_is_directory

      integer(c_int) function c_parse_double(text, length, value) bind(C, name='twomem_sys_parse_double')
         import :: c_char, c_int, c_double
         character(kind=c_char), intent(in) :: text(*)
         integer(c_int), value :: length
         real(c_double), intent(out) :: value
      end function c_parse_double

      integer(c_int) function c_getpid() bind(C, name='twomem_sys_getpid')
         import :: c_int
      end function c_getpid

      integer(c_int64_t) function c_peak_rss_kib() bind(C, name='twomem_sys_peak_rss_kib')
         import :: c_int64_t
      end function c_peak_rss_kib

      subroutine c_keep_freed_memory() bind(C, name='twomem_sys_keep_freed_memory')
      end subroutine c_keep_freed_memory

      subroutine c_return_freed_memory() bind(C, name='twomem_sys_return_freed_memory')
      end subroutine c_return_freed_memory

      integer(c_int64_t) function c_memory_allowed(which, cap) bind(C, name='twomem_sys_memory_allowed')
         import :: c_int64_t, c_char, c_size_t
         character(kind=c_char), intent(out) :: which(*)
         integer(c_size_t), value :: cap
      end function c_memory_allowed

      integer(c_int) function c_guard_install(print) bind(C, name='twomem_guard_install')
         import :: c_int
         integer(c_int), value :: print
      end function c_guard_install

      integer(c_int) function c_guard_register(path) bind(C, name='twomem_guard_register')
         import :: c_int, c_char
         character(kind=c_char), intent(in) :: path(*)
      end function c_guard_register

      subroutine c_guard_unregister() bind(C, name='twomem_guard_unregister')
      end subroutine c_guard_unregister
   end interface

contains

   !> Create `path` and every missing parent, like `mkdir -p`; an existing directory is fine.
   subroutine make_directories(path, err)
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (len_trim(path) == 0) return
      if (c_make_directories(trim(path)//c_null_char, msg, len(msg, c_size_t)) /= 0) &
         call make_error(err, exit_io, path, c_text(msg))
   end subroutine make_directories

   !> POSIX rename: atomic when both names are on the same filesystem, and replaces `to`.
   subroutine rename_file(from, to, err)
      character(len=*), intent(in) :: from, to
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (c_rename(trim(from)//c_null_char, trim(to)//c_null_char, msg, len(msg, c_size_t)) /= 0) &
         call make_error(err, exit_io, from, c_text(msg))
   end subroutine rename_file

   !> Remove a file; one that does not exist is not an error. `err` is optional because
   !> clean-up after another failure has nothing better to do with a second one.
   subroutine remove_file(path, err)
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out), optional :: err

      character(len=msg_len) :: msg

      if (c_remove(trim(path)//c_null_char, msg, len(msg, c_size_t)) /= 0) then
         if (present(err)) call make_error(err, exit_io, path, c_text(msg))
      end if
   end subroutine remove_file

   !> Whether anything (file, directory, ...) exists at `path`.
   logical function file_exists(path)
      character(len=*), intent(in) :: path

      file_exists = c_exists(trim(path)//c_null_char) == 1
   end function file_exists

   logical function is_directory(path)
      character(len=*), intent(in) :: path

      is_directory = c_is_directory(trim(path)//c_null_char) == 1
   end function is_directory

   !> End the program with exit status `code` (docs/input.md, docs/usage.md), after flushing standard output
   !> and error so that the last progress line and the error message are not lost.
   subroutine exit_program(code)
      integer, intent(in) :: code

      flush (output_unit)
      flush (error_unit)
      call c_exit(int(code, c_int))
   end subroutine exit_program

   integer function process_id()
      process_id = int(c_getpid())
   end function process_id

   !> Peak resident set size of this process so far, in KiB; -1 if unknown.
   integer(i8) function peak_memory_kib()
      peak_memory_kib = int(c_peak_rss_kib(), i8)
   end function peak_memory_kib

   !> Reuse freed memory instead of handing it back to the kernel, which zeroes it again on the
   !> next allocation (src/c/twomem_system.c says when and why); call before the first large
   !> allocation.
   subroutine keep_freed_memory()
      call c_keep_freed_memory()
   end subroutine keep_freed_memory

   !> Give the heap's free pages back to the kernel at once (src/c/twomem_system.c): after
   !> freeing a large structure whose memory the next allocations cannot reuse as it lies.
   subroutine return_freed_memory()
      call c_return_freed_memory()
   end subroutine return_freed_memory

   !> How many more bytes this process may allocate (the least of available memory, ulimit -v
   !> and -d, the cgroup limit; see src/c/twomem_system.c) and which limit decided; -1 if
   !> nothing is known.
   integer(i8) function memory_allowed_bytes(which)
      character(len=:), allocatable, intent(out) :: which

      character(len=256) :: buffer

      memory_allowed_bytes = int(c_memory_allowed(buffer, len(buffer, c_size_t)), i8)
      which = c_text(buffer)
   end function memory_allowed_bytes

   !> SIGTERM and SIGINT end the run at once with `twomem: interrupted by SIG...` (printed
   !> when `print`) and exit status 128 + signo, after removing the registered temporary file;
   !> a failed allocation ends it with one line and exit 3. Why a handler that exits rather
   !> than a polled flag: src/c/twomem_guard.c.
   subroutine install_guards(print)
      logical, intent(in) :: print

      integer(c_int) :: status

      ! a handler that cannot be installed leaves the default action (the run still ends)
      status = c_guard_install(merge(1_c_int, 0_c_int, print))
   end subroutine install_guards

   !> `path` is the temporary file about to be created: removed if the run is killed before
   !> `unregister_temporary`. Call before creating it.
   subroutine register_temporary(path)
      character(len=*), intent(in) :: path

      integer(c_int) :: status

      ! too long a path (over 4 KiB) is written all the same, only without clean-up on a signal
      status = c_guard_register(trim(path)//c_null_char)
   end subroutine register_temporary

   subroutine unregister_temporary()
      call c_guard_unregister()
   end subroutine unregister_temporary

   !> The directory part of `path`, as dirname(1): 'a/b.h5' -> 'a', 'b.h5' -> '.', '/b' -> '/'.
   pure function parent_directory(path) result(parent)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: parent

      integer :: n, k

      n = strip_slashes(path, len_trim(path))
      if (n == 0) then
         parent = merge('/', '.', len_trim(path) > 0)
         return
      end if
      k = index(path(1:n), '/', back=.true.)
      if (k == 0) then
         parent = '.'
         return
      end if
      n = strip_slashes(path, k - 1)
      if (n == 0) then
         parent = '/'
      else
         parent = path(1:n)
      end if
   end function parent_directory

   !> The last component of `path`, as basename(1): 'a/b.h5' -> 'b.h5', 'a/b/' -> 'b'.
   pure function base_name(path) result(name)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: name

      integer :: n

      n = strip_slashes(path, len_trim(path))
      if (n == 0) then
         name = merge('/', ' ', len_trim(path) > 0)
         name = trim(name)
         return
      end if
      name = path(index(path(1:n), '/', back=.true.) + 1:n)
   end function base_name

   !> Length of path(1:n) without its trailing slashes.
   pure integer function strip_slashes(path, n) result(m)
      character(len=*), intent(in) :: path
      integer, intent(in) :: n

      m = n
      do while (m > 0)
         if (path(m:m) /= '/') exit
         m = m - 1
      end do
   end function strip_slashes

   !> The value of the decimal token `text` ([sign] digits [. digits] [(e|E|d|D) [sign] digits],
   !> checked by the caller, within the range of real64); .false. where the C library does not
   !> convert it whole or it is longer than 63 characters (the caller then reads it itself).
   logical function decimal_value(text, value) result(ok)
      character(len=*), intent(in) :: text
      real(dp), intent(out) :: value

      real(c_double) :: converted

      ok = c_parse_double(text, int(len(text), c_int), converted) == 0
      value = converted
   end function decimal_value

   !> The text of a NUL-terminated C string in a Fortran buffer (the C glue's messages).
   pure function c_text(buffer) result(text)
      character(len=*), intent(in) :: buffer
      character(len=:), allocatable :: text

      integer :: n

      n = index(buffer, c_null_char) - 1
      if (n < 0) n = len_trim(buffer)
      text = buffer(1:n)
   end function c_text
end module twomem_base_system
