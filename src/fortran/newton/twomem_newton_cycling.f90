!> Cycling detection for exact Newton-min, a primal–dual active set method: with full steps and
!> exact solves its iterate is a function of the active set alone, so meeting a set again
!> means the iteration will repeat forever. Each Newton step's active set is remembered by its
!> size and two hashes; a damped step breaks the map from set to iterate, so sets are only
!> compared since the last damped step. The hashes add a pseudo-random value per active
!> vertex, keyed by its whole-mesh number: they are independent of the order in which ranks and
!> threads visit the vertices, so every rank of a distributed run finds the same set.
module twomem_newton_cycling
   use twomem_base_kinds, only: ip, i8
   use twomem_base_comm, only: comm_t
   use twomem_linalg_vectors, only: threaded_from
   implicit none
   private

   public :: active_set_watch_t

   type :: active_set_watch_t
      integer(i8), allocatable :: hash(:, :)
      integer, allocatable :: size(:)
      integer :: last_damped = 0
   contains
      procedure :: init
      procedure :: record
      procedure :: damped
      procedure :: repeats
   end type active_set_watch_t

   !> moduli of the two hashes: primes below 2**31, so 2**31 terms cannot overflow 64 bits
   integer(i8), parameter :: p1 = 2147483647_i8, p2 = 2147483629_i8

contains

   !> Room for steps 0..max_it.
   subroutine init(self, max_it)
      class(active_set_watch_t), intent(inout) :: self
      integer, intent(in) :: max_it

      if (allocated(self%hash)) deallocate (self%hash, self%size)
      allocate (self%hash(2, 0:max_it), self%size(0:max_it))
      self%last_damped = 0
   end subroutine init

   !> The active set of step k: active(i) for the unknowns with whole-mesh numbers global(i),
   !> counted where `owned`. Collective.
   subroutine record(self, k, active, global, owned, comm)
      class(active_set_watch_t), intent(inout) :: self
      integer, intent(in) :: k
      logical, intent(in) :: active(:), owned(:)
      integer(ip), intent(in) :: global(:)
      type(comm_t), intent(in) :: comm

      integer(i8) :: h1, h2
      integer(ip) :: i, n
      integer :: members

      n = size(active, kind=ip)
      h1 = 0
      h2 = 0
      members = 0
      ! integer sums: the threads' order does not change them
      !$omp parallel do default(none) shared(active, owned, global, n) private(i) &
      !$omp reduction(+:h1, h2, members) schedule(static) if(n > threaded_from)
      do i = 1, n
         if (active(i) .and. owned(i)) then
            h1 = h1 + mix(int(global(i), i8), 1_i8)
            h2 = h2 + mix(int(global(i), i8), 2_i8)
            members = members + 1
         end if
      end do
      !$omp end parallel do
      self%hash(1, k) = mod(comm%sum(h1), p1)
      self%hash(2, k) = mod(comm%sum(h2), p2)
      self%size(k) = comm%sum(members)
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
         if (all(self%hash(:, j) == self%hash(:, k)) .and. self%size(j) == self%size(k)) then
            repeats = .true.
            return
         end if
      end do
   end function repeats

   !> A pseudo-random value in [0, p) for vertex number v (two rounds of a multiplicative mix,
   !> distinct for the two hashes through `seed`).
   pure integer(i8) function mix(v, seed) result(h)
      integer(i8), intent(in) :: v, seed

      integer(i8), parameter :: a = 1000003_i8, b = 999983_i8

      h = mod(v*a + seed*7919_i8, p1)
      h = mod(h*b + seed, merge(p1, p2, seed == 1))
   end function mix
end module twomem_newton_cycling
