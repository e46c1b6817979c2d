!> Cycling detection for exact Newton-min, a primal–dual active set method: with full steps and
!> exact solves its iterate is a function of the active set alone, so meeting a set again
!> means the iteration will repeat forever. Each Newton step's active set is remembered as two
!> polynomial hashes and its size; a damped step breaks the map from set to iterate, so sets
!> are only compared since the last damped step.
module twomem_newton_cycling
   use twomem_base_kinds, only: ip, i8
   implicit none
   private

   public :: active_set_watch_t

   type :: active_set_watch_t
      integer(i8), allocatable :: hash(:)
      integer, allocatable :: size(:)
      integer :: last_damped = 0
   contains
      procedure :: init
      procedure :: record
      procedure :: damped
      procedure :: repeats
   end type active_set_watch_t

contains

   !> Room for steps 0..max_it.
   subroutine init(self, max_it)
      class(active_set_watch_t), intent(inout) :: self
      integer, intent(in) :: max_it

      if (allocated(self%hash)) deallocate (self%hash, self%size)
      allocate (self%hash(0:max_it), self%size(0:max_it))
      self%last_damped = 0
   end subroutine init

   subroutine record(self, k, active)
      class(active_set_watch_t), intent(inout) :: self
      integer, intent(in) :: k
      logical, intent(in) :: active(:)

      self%hash(k) = hash_set(active)
      self%size(k) = count(active)
   end subroutine record

   !> Step k was damped by the line search.
   subroutine damped(self, k)
      class(active_set_watch_t), intent(inout) :: self
      integer, intent(in) :: k

      self%last_damped = k
   end subroutine damped

   !> The active set of step k was met before (since the last damped step, excluding step k−1,
   !> whose repetition means convergence or a round-off floor, reported separately).
   logical function repeats(self, k)
      class(active_set_watch_t), intent(in) :: self
      integer, intent(in) :: k

      integer :: j

      repeats = .false.
      do j = self%last_damped, k - 2
         if (self%hash(j) == self%hash(k) .and. self%size(j) == self%size(k)) then
            repeats = .true.
            return
         end if
      end do
   end function repeats

   !> Hash of the active set (two polynomial hashes modulo primes below 2**31, so no product
   !> overflows 64 bits).
   pure integer(i8) function hash_set(active) result(h)
      logical, intent(in) :: active(:)

      integer(i8), parameter :: p1 = 2147483647_i8, p2 = 2147483629_i8
      integer(i8) :: h1, h2
      integer(ip) :: i

      h1 = 0
      h2 = 0
      do i = 1, size(active, kind=ip)
         if (active(i)) then
            h1 = mod(h1*1000003_i8 + i, p1)
            h2 = mod(h2*999983_i8 + i, p2)
         end if
      end do
      h = h1*p2 + h2
   end function hash_set
end module twomem_newton_cycling
