!> The one place where numeric kinds are chosen. Everything real is `real(dp)`; local indices are
!> `integer(ip)`, kept 32-bit so that CSR arrays stay compact and can be handed to UMFPACK's `int`
!> interface without copies. Large global counts (later, across MPI ranks) will get their own kind.
module twomem_base_kinds
   use, intrinsic :: iso_fortran_env, only: real64, int32, int64
   implicit none
   private

   public :: dp, ip, i8

   integer, parameter :: dp = real64
   integer, parameter :: ip = int32
   integer, parameter :: i8 = int64
end module twomem_base_kinds
