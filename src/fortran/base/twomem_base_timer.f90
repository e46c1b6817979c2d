!> Wall-clock time for progress lines and the run summary. One 64-bit `system_clock` so that
!> the count neither wraps during a long run nor loses resolution; only differences are meaningful.
module twomem_base_timer
   use, intrinsic :: iso_fortran_env, only: int64
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: wall_time

contains

   !> Seconds since an arbitrary fixed origin.
   function wall_time() result(seconds)
      real(dp) :: seconds

      integer(int64) :: count, rate

      call system_clock(count, rate)
      seconds = real(count, dp)/real(rate, dp)
   end function wall_time
end module twomem_base_timer
