!> The fuzzer's own pseudo-random numbers: xorshift64 on a 64-bit integer, written with shifts
!> and exclusive ors only. No multiplication or addition touches the state, so nothing overflows
!> (signed overflow is undefined in Fortran and UBSan would object), and the sequence is the same
!> on every machine and compiler. Each input gets its own stream, derived from the seed and the
!> input's number, so any single input can be replayed without generating the ones before it.
module fuzz_random
   use twomem_base_kinds, only: dp, i8
   implicit none
   private

   public :: rng_t

   type :: rng_t
      integer(i8) :: state = 88172645463325252_i8
   contains
      procedure :: init => rng_init
      procedure :: next => rng_next
      procedure :: below
      procedure :: between
      procedure :: chance
   end type rng_t

contains

   !> Stream number `stream` of generator `seed`. The warm-up spreads seeds that differ in a few
   !> bits over the whole state before the first number is drawn.
   subroutine rng_init(self, seed, stream)
      class(rng_t), intent(inout) :: self
      integer(i8), intent(in) :: seed, stream

      integer :: i
      integer(i8) :: x

      self%state = ieor(ieor(seed, ishft(stream, 32)), ishft(stream, -7))
      self%state = ieor(self%state, 6148914691236517205_i8)
      if (self%state == 0) self%state = 88172645463325252_i8
      do i = 1, 16
         x = self%next()
      end do
   end subroutine rng_init

   !> A non-negative number below 2**31.
   integer(i8) function rng_next(self) result(r)
      class(rng_t), intent(inout) :: self

      integer(i8) :: x

      x = self%state
      x = ieor(x, ishft(x, 13))
      x = ieor(x, ishft(x, -7))
      x = ieor(x, ishft(x, 17))
      self%state = x
      ! the high bits are the better mixed ones; 31 of them stay clear of the sign
      r = ishft(x, -33)
   end function rng_next

   !> Uniform in 0 .. n-1 (n >= 1).
   integer function below(self, n)
      class(rng_t), intent(inout) :: self
      integer, intent(in) :: n

      below = int(modulo(self%next(), int(max(n, 1), i8)))
   end function below

   !> Uniform in lo .. hi.
   integer function between(self, lo, hi)
      class(rng_t), intent(inout) :: self
      integer, intent(in) :: lo, hi

      between = lo + self%below(hi - lo + 1)
   end function between

   !> True with probability p.
   logical function chance(self, p)
      class(rng_t), intent(inout) :: self
      real(dp), intent(in) :: p

      chance = real(self%next(), dp) < p*2147483648.0_dp
   end function chance
end module fuzz_random
