!> Numbers as text for the progress output and messages: fixed decimals with the leading zero
!> that `f0.d` drops ('.43'), and integers without blanks: the one place every module takes
!> them from.
module twomem_base_text
   use twomem_base_kinds, only: dp, i8
   implicit none
   private

   public :: fixed, int_text

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
end module twomem_base_text
