!> Errors travel as values. Library code never stops the program: it allocates an `error_t`
!> naming where and what went wrong, and returns; only the program turns it into the one-line
!> message and the exit code of docs/input.md. The category fixes the exit code, so a routine deep
!> down decides whether a failure is bad input (2) or the environment's fault (3).
module twomem_base_errors
   implicit none
   private

   public :: error_t, make_error, prefix_error, excerpt
   public :: exit_ok, exit_not_converged, exit_bad_input, exit_io

   integer, parameter :: exit_ok = 0
   integer, parameter :: exit_not_converged = 1
   integer, parameter :: exit_bad_input = 2
   integer, parameter :: exit_io = 3

   !> Most characters of input text a message quotes: enough to recognize it, and a 70 000-
   !> character token does not become a 70 000-character message.
   integer, parameter :: excerpt_len = 80

   type :: error_t
      !> exit code category (`exit_bad_input` or `exit_io`)
      integer :: code = exit_bad_input
      character(len=:), allocatable :: message
   end type error_t

contains

   !> Allocate `err` with a message; `where` names the file, group or key when known.
   subroutine make_error(err, code, where, what)
      type(error_t), allocatable, intent(out) :: err
      integer, intent(in) :: code
      character(len=*), intent(in) :: where
      character(len=*), intent(in) :: what

      allocate (err)
      err%code = code
      if (len_trim(where) > 0) then
         err%message = trim(where)//': '//trim(what)
      else
         err%message = trim(what)
      end if
   end subroutine make_error

   !> Put context in front of an existing message (e.g. the file name a reader did not know).
   subroutine prefix_error(err, where)
      type(error_t), intent(inout) :: err
      character(len=*), intent(in) :: where

      err%message = trim(where)//': '//err%message
   end subroutine prefix_error

   !> Input text as a message may quote it: control characters (a newline would split the
   !> one-line message, an escape would garble the terminal) written as <0xHH>, and text beyond
   !> about `excerpt_len` characters cut off with '...'.
   pure function excerpt(text) result(shown)
      character(len=*), intent(in) :: text
      character(len=:), allocatable :: shown

      character(len=*), parameter :: hex = '0123456789ABCDEF'
      integer :: i, c

      shown = ''
      do i = 1, len(text)
         if (len(shown) >= excerpt_len) then
            shown = shown//'...'
            exit
         end if
         c = iachar(text(i:i))
         if (c < 32 .or. c == 127) then
            shown = shown//'<0x'//hex(c/16 + 1:c/16 + 1)//hex(mod(c, 16) + 1:mod(c, 16) + 1)//'>'
         else
            shown = shown//text(i:i)
         end if
      end do
   end function excerpt
end module twomem_base_errors
