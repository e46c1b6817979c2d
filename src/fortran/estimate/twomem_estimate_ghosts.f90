!> Per-triangle values of a rank's ghost layer, copied from the triangles' owners. The
!> estimators evaluate every quantity of a triangle on its owner only, where all of it is known
!> (∇u_h, the residual lifting: on a ghost triangle some vertices may lie outside this rank's
!> unknowns), and the patches of this rank's vertices read the ghost triangles' copies. The
!> pattern is fixed on the coarse mesh: rank q's coarse triangle T is a ghost on rank p exactly
!> when T shares a vertex with a triangle p owns, which q sees in its own ghost layer, so both
!> sides list the same triangles (in whole-mesh order) without asking each other. A level-l
!> triangle descends from coarse triangle t as one of the 4^l consecutive numbers
!> 4^l (t − 1) + 1 .. 4^l t, locally and in the whole mesh alike, so the coarse lists serve every
!> level; the coarse ghosts come after the rank's own triangles, so the ghosts of every level are
!> its last triangles. `fill` writes the owners' values into a whole level's array, `share` into
!> one of the ghost layer's size. With one rank there are no ghosts and both do nothing.
module twomem_estimate_ghosts
   use twomem_base_kinds, only: dp, ip
   use twomem_base_comm, only: comm_t
   use twomem_base_sort, only: sorting_permutation
   use twomem_mesh_triangulation, only: mesh_t
   implicit none
   private

   public :: ghost_cells_t

   type :: ghost_cells_t
      type(comm_t) :: comm
      !> neighbour ranks (ascending); coarse triangles sent to neighbours(k) are
      !> send_coarse(send_ptr(k):send_ptr(k+1)−1), received ones recv_coarse(recv_ptr(k):...)
      integer, allocatable :: neighbours(:)
      integer, allocatable :: send_ptr(:), recv_ptr(:)
      integer(ip), allocatable :: send_coarse(:), recv_coarse(:)
      !> the coarse mesh's own triangles: the ghosts are those after them
      integer(ip) :: coarse_owned = 0
   contains
      procedure :: init
      procedure :: has_neighbours
      procedure :: sent_triangles
      procedure :: share
      procedure, private :: fill_rows, fill_values
      !> values(:, t) or values(t) of the ghost triangles of a level from their owners
      generic :: fill => fill_rows, fill_values
   end type ghost_cells_t

contains

   !> The pattern from this rank's piece of the coarse mesh (level 0 of its hierarchy).
   subroutine init(self, comm, coarse)
      class(ghost_cells_t), intent(out) :: self
      type(comm_t), intent(in) :: comm
      type(mesh_t), intent(in) :: coarse

      logical, allocatable :: sends(:, :), neighbour(:)
      integer(ip), allocatable :: order(:)
      integer(ip) :: t, m, s
      integer :: i, k, q, n

      self%comm = comm
      self%coarse_owned = coarse%nt_owned
      allocate (sends(coarse%nt_owned, 0:comm%size - 1), neighbour(0:comm%size - 1))
      sends = .false.
      do t = 1, coarse%nt_owned
         do i = 1, 3
            associate (a => coarse%triangles(i, t))
               do m = coarse%patch_ptr(a), coarse%patch_ptr(a + 1) - 1
                  q = coarse%triangle_owner_of(coarse%patch_triangles(m))
                  if (q /= comm%rank) sends(t, q) = .true.
               end do
            end associate
         end do
      end do
      neighbour = any(sends, dim=1)
      do t = coarse%nt_owned + 1, coarse%nt
         neighbour(coarse%triangle_owner_of(t)) = .true.
      end do
      self%neighbours = pack([(q, q=0, comm%size - 1)], neighbour)
      n = size(self%neighbours)
      allocate (self%send_ptr(n + 1), self%recv_ptr(n + 1))
      allocate (self%send_coarse(count(sends)), self%recv_coarse(coarse%nt - coarse%nt_owned))
      ! both lists in whole-mesh order
      order = sorting_permutation(coarse%global_triangle_of([(t, t=1, coarse%nt)]))
      self%send_ptr(1) = 1
      self%recv_ptr(1) = 1
      do k = 1, n
         q = self%neighbours(k)
         self%send_ptr(k + 1) = self%send_ptr(k)
         self%recv_ptr(k + 1) = self%recv_ptr(k)
         do s = 1, size(order, kind=ip)
            t = order(s)
            if (t <= coarse%nt_owned) then
               if (sends(t, q)) then
                  self%send_coarse(self%send_ptr(k + 1)) = t
                  self%send_ptr(k + 1) = self%send_ptr(k + 1) + 1
               end if
            else if (coarse%triangle_owner_of(t) == q) then
               self%recv_coarse(self%recv_ptr(k + 1)) = t
               self%recv_ptr(k + 1) = self%recv_ptr(k + 1) + 1
            end if
         end do
      end do
   end subroutine init

   !> values(:, t) of the ghost triangles of level `level` from their owners. Collective among
   !> neighbours.
   subroutine fill_rows(self, level, values)
      class(ghost_cells_t), intent(in) :: self
      integer, intent(in) :: level
      real(dp), intent(inout), contiguous :: values(:, :)

      call fill_block(self, level, size(values, 1), size(values, 2, kind=ip), values)
   end subroutine fill_rows

   subroutine fill_values(self, level, values)
      class(ghost_cells_t), intent(in) :: self
      integer, intent(in) :: level
      real(dp), intent(inout), contiguous :: values(:)

      call fill_block(self, level, 1, size(values, kind=ip), values)
   end subroutine fill_values

   subroutine fill_block(self, level, width, nt, values)
      class(ghost_cells_t), intent(in) :: self
      integer, intent(in) :: level, width
      integer(ip), intent(in) :: nt
      real(dp), intent(inout) :: values(width, nt)

      integer(ip), allocatable :: sent(:)
      integer(ip) :: n_ghost

      if (size(self%neighbours) == 0) return
      sent = self%sent_triangles(level)
      n_ghost = size(self%recv_coarse, kind=ip)*4_ip**level
      call self%share(level, values(:, sent), values(:, nt - n_ghost + 1:))
   end subroutine fill_block

   !> Whether this rank has ghost triangles (and other ranks its triangles as theirs).
   pure logical function has_neighbours(self)
      class(ghost_cells_t), intent(in) :: self

      has_neighbours = size(self%neighbours) > 0
   end function has_neighbours

   !> The triangles of level `level` whose values go to the neighbours, in the order `share`
   !> takes them (repeats where several neighbours receive a triangle).
   function sent_triangles(self, level) result(list)
      class(ghost_cells_t), intent(in) :: self
      integer, intent(in) :: level
      integer(ip), allocatable :: list(:)

      integer(ip) :: generations, j, c, f, n

      generations = 4_ip**level
      allocate (list(size(self%send_coarse, kind=ip)*generations))
      n = 0
      do j = 1, size(self%send_coarse, kind=ip)
         c = self%send_coarse(j)
         do f = (c - 1)*generations + 1, c*generations
            n = n + 1
            list(n) = f
         end do
      end do
   end function sent_triangles

   !> tail(:, t − nt_owned) = the owner's values on each ghost triangle t of level `level` (the
   !> tail of the level's triangles), from sent(:, k) = this rank's values on
   !> sent_triangles(level)'s k-th triangle. Collective among neighbours.
   subroutine share(self, level, sent, tail)
      class(ghost_cells_t), intent(in) :: self
      integer, intent(in) :: level
      real(dp), intent(in) :: sent(:, :)
      real(dp), intent(out) :: tail(:, :)

      real(dp), allocatable :: send(:), recv(:)
      integer, allocatable :: send_ptr(:), recv_ptr(:)
      integer(ip) :: generations, j, c, at
      integer :: k, width

      if (size(self%neighbours) == 0) return
      width = size(sent, 1)
      generations = 4_ip**level
      send_ptr = 1 + (self%send_ptr - 1)*width*int(generations)
      recv_ptr = 1 + (self%recv_ptr - 1)*width*int(generations)
      send = reshape(sent, [size(sent)])
      allocate (recv(recv_ptr(size(recv_ptr)) - 1))
      call self%comm%exchange(self%neighbours, send, send_ptr, recv, recv_ptr)
      ! the coarse ghosts are the tail after the coarse mesh's own triangles, so their
      ! descendants are the tail of every level, in the same order
      at = 1
      do k = 1, size(self%neighbours)
         do j = self%recv_ptr(k), self%recv_ptr(k + 1) - 1
            c = self%recv_coarse(j)
            tail(:, (c - self%coarse_owned - 1)*generations + 1:(c - self%coarse_owned)*generations) = &
               reshape(recv(at:at + width*generations - 1), [width, int(generations)])
            at = at + width*generations
         end do
      end do
   end subroutine share
end module twomem_estimate_ghosts
