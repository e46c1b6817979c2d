!> Numbers as text for the progress output: fixed decimals with the leading zero that `f0.d`
!> drops ('.43').
module twomem_base_text
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: fixed

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
end module twomem_base_text
