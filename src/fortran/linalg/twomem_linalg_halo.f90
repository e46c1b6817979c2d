!> The interface of a rank's piece of a distributed vector: the entries it shares with
!> neighbour ranks, and which entries it owns. Matrices are assembled per rank over its own
!> triangles, so a product gives every shared entry only this rank's part of it; `add` sums the
!> parts, after which every rank holds the full value (an "accumulated" vector). The sum is
!> taken in ascending rank order on every rank, own part included, so all sharers compute the
!> same bits and the copies of a shared entry can never drift apart. `owned` marks the entries
!> this rank counts in global sums (each entry is owned by exactly one rank). With one rank
!> there is nothing to share, every entry is owned, and `add` does nothing.
module twomem_linalg_halo
   use twomem_base_kinds, only: dp, ip
   use twomem_base_comm, only: comm_t
   implicit none
   private

   public :: halo_t

   type :: halo_t
      type(comm_t) :: comm
      !> neighbour ranks in ascending order; entries idx(ptr(k):ptr(k+1)−1) are shared with
      !> neighbours(k), listed in the order both sides agree on (global number)
      integer, allocatable :: neighbours(:), ptr(:)
      integer(ip), allocatable :: idx(:)
      !> the distinct shared entries, and entries this rank owns
      integer(ip), allocatable :: shared(:)
      logical, allocatable :: owned(:)
      real(dp), allocatable :: send(:), recv(:), total(:)
      !> position in `shared` of each idx entry
      integer(ip), allocatable :: slot(:)
   contains
      procedure :: init
      procedure :: init_whole
      procedure :: add
      procedure :: n_owned
   end type halo_t

contains

   !> n local entries; owner(i) the rank owning entry i; neighbour lists as described above.
   subroutine init(self, comm, owner, neighbours, ptr, idx)
      class(halo_t), intent(out) :: self
      type(comm_t), intent(in) :: comm
      integer, intent(in) :: owner(:)
      integer, intent(in) :: neighbours(:), ptr(:)
      integer(ip), intent(in) :: idx(:)

      integer(ip), allocatable :: where(:)
      integer(ip) :: j, n_shared

      self%comm = comm
      self%neighbours = neighbours
      self%ptr = ptr
      self%idx = idx
      self%owned = owner == comm%rank
      allocate (where(size(owner)))
      where = 0
      n_shared = 0
      allocate (self%slot(size(idx)))
      do j = 1, size(idx)
         if (where(idx(j)) == 0) then
            n_shared = n_shared + 1
            where(idx(j)) = n_shared
         end if
         self%slot(j) = where(idx(j))
      end do
      allocate (self%shared(n_shared))
      do j = 1, size(idx)
         self%shared(self%slot(j)) = idx(j)
      end do
      allocate (self%send(size(idx)), self%recv(size(idx)), self%total(n_shared))
   end subroutine init

   !> A whole vector of n entries on one rank: nothing shared, all owned.
   subroutine init_whole(self, comm, n)
      class(halo_t), intent(out) :: self
      type(comm_t), intent(in) :: comm
      integer(ip), intent(in) :: n

      self%comm = comm
      allocate (self%neighbours(0), self%ptr(1), self%idx(0), self%shared(0), self%slot(0), self%send(0), &
                self%recv(0), self%total(0))
      self%ptr = 1
      allocate (self%owned(n))
      self%owned = .true.
   end subroutine init_whole

   !> Sum the ranks' parts of every shared entry of x (collective among neighbours).
   subroutine add(self, x)
      class(halo_t), intent(inout) :: self
      real(dp), intent(inout) :: x(:)

      integer :: k
      integer(ip) :: j
      logical :: own_added

      if (size(self%neighbours) == 0) return
      do j = 1, size(self%idx, kind=ip)
         self%send(j) = x(self%idx(j))
      end do
      call self%comm%exchange(self%neighbours, self%send, self%ptr, self%recv, self%ptr)
      ! ascending rank order, own part at its place: the same sum on every sharer
      self%total = 0.0_dp
      own_added = .false.
      do k = 1, size(self%neighbours)
         if (.not. own_added .and. self%neighbours(k) > self%comm%rank) then
            call add_own()
            own_added = .true.
         end if
         do j = self%ptr(k), self%ptr(k + 1) - 1
            self%total(self%slot(j)) = self%total(self%slot(j)) + self%recv(j)
         end do
      end do
      if (.not. own_added) call add_own()
      do j = 1, size(self%shared, kind=ip)
         x(self%shared(j)) = self%total(j)
      end do

   contains

      subroutine add_own()
         integer(ip) :: m

         do m = 1, size(self%shared, kind=ip)
            self%total(m) = self%total(m) + x(self%shared(m))
         end do
      end subroutine add_own
   end subroutine add

   integer(ip) function n_owned(self)
      class(halo_t), intent(in) :: self

      n_owned = count(self%owned, kind=ip)
   end function n_owned
end module twomem_linalg_halo
