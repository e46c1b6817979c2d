!> Text helpers for the progress output, messages and parsers: fixed decimals with the leading
!> zero that `f0.d` drops ('.43'), integers without blanks, and ASCII lower case; the one place
!> every module takes them from.
module twomem_base_text
   use twomem_base_kinds, only: dp, i8
   implicit none
   private

   public :: fixed, int_text, to_lower

   interface int_text
      module procedure int_text_default, int_text_i8
   end interface int_text

contains

   !> x with `digits` decimals and a leading zero.
   pure function fixed(x, digits) result(text)
      real(dp), intent(in) :: x
      integer, intent(in) :: digits
      character(len=:), allocatable :: text

      character(len=32) :: buffer, format

      write (format, '("(f32.",i0,")")') digits
      write (buffer, format) x
      text = trim(adjustl(buffer))
   end function fixed

   !> i in as many characters as it needs.
   pure function int_text_default(i) result(text)
      integer, intent(in) :: i
      character(len=:), allocatable :: text

      character(len=12) :: buffer

      write (buffer, '(i0)') i
      text = trim(buffer)
   end function int_text_default

   pure function int_text_i8(i) result(text)
      integer(i8), intent(in) :: i
      character(len=:), allocatable :: text

      character(len=24) :: buffer

      write (buffer, '(i0)') i
      text = trim(buffer)
   end function int_text_i8

   !> s with the ASCII capitals A–Z in lower case (keys, words and names are case-insensitive).
   pure function to_lower(s) result(l)
      character(len=*), intent(in) :: s
      character(len=len(s)) :: l

      integer :: i

      l = s
      do i = 1, len(s)
         if (s(i:i) >= 'A' .and. s(i:i) <= 'Z') l(i:i) = achar(iachar(s(i:i)) + 32)
      end do
   end function to_lower
end module twomem_base_text
