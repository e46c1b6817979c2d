!> Numbers as text for the progress output and messages: fixed decimals with the leading zero
!> that `f0.d` drops ('.43'), and integers without blanks.
module twomem_base_text
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: fixed, int_text

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
   pure function int_text(i) result(text)
      integer, intent(in) :: i
      character(len=:), allocatable :: text

      character(len=12) :: buffer

      write (buffer, '(i0)') i
      text = trim(buffer)
   end function int_text
end module twomem_base_text
