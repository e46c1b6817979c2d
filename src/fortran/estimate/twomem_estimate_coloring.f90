!> Block colourings for the patch loops. The vertices are grouped into blocks of neighbouring
!> patches, and the blocks are coloured so that two blocks of one colour never share a triangle:
!> the blocks of one colour can then add their patches' contributions into the flux coefficients
!> of their triangles in parallel without races, with no per-patch copies of the result (the
!> three vertex contributions of a triangle used to be stored apart and added afterwards, 48
!> numbers per triangle for RT1). A block is the vertices whose first patch triangle lies in one
!> run of consecutive triangles; red refinement numbers triangles along its tree, so a block is a
!> compact piece of the domain and one thread works through its patches with their triangles'
!> data in cache. A colouring of single vertices (no two of a colour sharing a triangle) needs
!> a sweep over all triangle data per colour, about seven, and so several times the memory
!> traffic (docs/performance.md, "Measurements behind design choices"). Blocks are coloured
!> greedily in order and run their vertices in order, so a result is summed in the same order
!> whatever the number of threads. On a rank's piece of a distributed mesh only the vertices of
!> its own triangles are listed: their patches are whole there (the ghost layer), the others'
!> are not and belong to other ranks.
module twomem_estimate_coloring
   use twomem_base_kinds, only: dp, ip
   use twomem_base_sort, only: sorting_permutation
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_spatial_order, only: z_order_key
   implicit none
   private

   public :: coloring_t

   !> At least this many blocks where the mesh allows it (several per colour and thread, for the
   !> dynamic schedule's balance), and at most this many triangles per block (the block's data
   !> well inside a core's cache: about 0.4 MB for RT1 and both membranes).
   integer(ip), parameter :: min_blocks = 256, max_block_triangles = 1024
   !> Blocks of a planar mesh numbered along its refinement tree need a handful of colours (4–8).
   !> More means a numbering without locality (a Gmsh mesh as the mesher numbered it: a block's
   !> first triangles are then scattered over the domain, conflicting with most other blocks, so
   !> that a colour holds one or two blocks and the loop runs on one thread, its patches' data
   !> never in cache): the blocks are then made anew from the vertices in the order of a
   !> Z-order curve through their positions (spatial_blocks).
   integer, parameter :: max_colors = 16

   type :: coloring_t
      !> the blocks of colour c are ptr(c):ptr(c+1)-1; block b lists the vertices
      !> vertices(block_ptr(b):block_ptr(b+1)-1)
      integer :: n_colors = 0
      integer(ip), allocatable :: ptr(:), block_ptr(:), vertices(:)
   contains
      procedure :: init
   end type coloring_t

contains

   subroutine init(self, mesh)
      class(coloring_t), intent(out) :: self
      type(mesh_t), intent(in) :: mesh

      integer(ip), allocatable :: block_of(:), first(:), members(:)
      integer, allocatable :: color(:)

      call make_blocks(mesh, block_of, first, members)
      call color_blocks(mesh, block_of, first, color)
      if (maxval(color) > max_colors) then
         call spatial_blocks(mesh, size(first) - 1, block_of, first, members)
         call color_blocks(mesh, block_of, first, color)
      end if
      call group_by_color(self, first, members, color)
   end subroutine init

   !> block_of(a): the block of vertex a (0 outside the rank's subdomain), the run of consecutive
   !> triangles its first patch triangle lies in; block b's vertices are
   !> members(first(b):first(b+1)-1), in the order of their first patch triangle.
   subroutine make_blocks(mesh, block_of, first, members)
      type(mesh_t), intent(in) :: mesh
      integer(ip), allocatable, intent(out) :: block_of(:), first(:), members(:)

      logical, allocatable :: inside(:)
      integer(ip), allocatable :: fill(:)
      integer(ip) :: a, t, span, n_blocks, b
      integer :: i

      inside = mesh%in_subdomain()
      span = max(1_ip, min(max_block_triangles, mesh%nt/min_blocks))
      n_blocks = (mesh%nt + span - 1)/span
      allocate (block_of(mesh%nv), first(n_blocks + 1))
      first = 0
      do a = 1, mesh%nv
         block_of(a) = 0
         if (.not. inside(a)) cycle
         ! patches list their triangles in ascending order
         block_of(a) = (mesh%patch_triangles(mesh%patch_ptr(a)) - 1)/span + 1
         first(block_of(a) + 1) = first(block_of(a) + 1) + 1
      end do
      first(1) = 1
      do b = 1, n_blocks
         first(b + 1) = first(b) + first(b + 1)
      end do
      allocate (members(first(n_blocks + 1) - 1), fill(n_blocks))
      fill = first(1:n_blocks)
      do t = 1, mesh%nt
         do i = 1, 3
            a = mesh%triangles(i, t)
            if (block_of(a) == 0 .or. mesh%patch_triangles(mesh%patch_ptr(a)) /= t) cycle
            members(fill(block_of(a))) = a
            fill(block_of(a)) = fill(block_of(a)) + 1
         end do
      end do
   end subroutine make_blocks

   !> The blocks of make_blocks, n_blocks of them, made of the vertices in the order of the
   !> Z-order (Morton) curve through their positions instead: consecutive runs of that order
   !> are compact pieces of the domain, whatever the numbering (twomem_mesh_spatial_order; its
   !> grid is far finer than the blocks); the sort is deterministic, so are the blocks.
   subroutine spatial_blocks(mesh, n_blocks, block_of, first, members)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: n_blocks
      integer(ip), allocatable, intent(out) :: block_of(:), first(:), members(:)

      logical, allocatable :: inside(:)
      integer(ip), allocatable :: keys(:), order(:), listed(:)
      real(dp) :: low(2), width
      integer(ip) :: a, k, n, per_block, b

      inside = mesh%in_subdomain()
      low = minval(mesh%vertices, dim=2)
      width = max(maxval(mesh%vertices(1, :)) - low(1), maxval(mesh%vertices(2, :)) - low(2), tiny(1.0_dp))
      n = count(inside, kind=ip)
      allocate (keys(n), listed(n))
      k = 0
      do a = 1, mesh%nv
         if (.not. inside(a)) cycle
         k = k + 1
         listed(k) = a
         keys(k) = z_order_key(mesh%vertices(:, a), low, width)
      end do
      order = sorting_permutation(keys)
      per_block = max(1_ip, (n + n_blocks - 1)/n_blocks)
      allocate (block_of(mesh%nv), first(n_blocks + 1), members(n))
      block_of = 0
      first(1) = 1
      do b = 1, n_blocks
         first(b + 1) = min(n, b*per_block) + 1
      end do
      do k = 1, n
         a = listed(order(k))
         members(k) = a
         block_of(a) = (k - 1)/per_block + 1
      end do
   end subroutine spatial_blocks

   !> Greedy colours of the non-empty blocks in block order (0 for an empty one): two blocks
   !> conflict when vertices of theirs are corners of one triangle, i.e. their patches share it.
   subroutine color_blocks(mesh, block_of, first, color)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: block_of(:), first(:)
      integer, allocatable, intent(out) :: color(:)

      integer(ip), allocatable :: adj_ptr(:), adj(:), fill(:)
      logical, allocatable :: used(:)
      integer(ip) :: t, n_blocks, b, m
      integer :: pass

      n_blocks = size(first) - 1
      ! the conflicts as adjacency lists, counted in the first pass and filled in the second
      ! (a pair is listed once per triangle it shares: repeats only repeat a mark below)
      allocate (adj_ptr(n_blocks + 1), adj(0), fill(n_blocks))
      adj_ptr = 0
      do pass = 1, 2
         if (pass == 2) then
            adj_ptr(1) = 1
            do b = 1, n_blocks
               adj_ptr(b + 1) = adj_ptr(b) + adj_ptr(b + 1)
            end do
            deallocate (adj)
            allocate (adj(adj_ptr(n_blocks + 1) - 1))
            fill = adj_ptr(1:n_blocks)
         end if
         do t = 1, mesh%nt
            call conflicts_of(block_of(mesh%triangles(:, t)), pass)
         end do
      end do
      allocate (color(n_blocks), used(max(0_ip, maxval(adj_ptr(2:) - adj_ptr(:n_blocks))) + 1))
      color = 0
      do b = 1, n_blocks
         if (first(b + 1) == first(b)) cycle
         used = .false.
         do m = adj_ptr(b), adj_ptr(b + 1) - 1
            if (color(adj(m)) > 0) used(color(adj(m))) = .true.
         end do
         color(b) = findloc(used, .false., dim=1)
      end do

   contains

      subroutine conflicts_of(nb, pass)
         integer(ip), intent(in) :: nb(3)
         integer, intent(in) :: pass

         integer :: i, j

         do i = 1, 3
            do j = 1, 3
               if (i == j .or. nb(i) == 0 .or. nb(j) == 0 .or. nb(i) == nb(j)) cycle
               if (pass == 1) then
                  adj_ptr(nb(i) + 1) = adj_ptr(nb(i) + 1) + 1
               else
                  adj(fill(nb(i))) = nb(j)
                  fill(nb(i)) = fill(nb(i)) + 1
               end if
            end do
         end do
      end subroutine conflicts_of
   end subroutine color_blocks

   !> The blocks grouped by colour (each colour's in block order) into self.
   subroutine group_by_color(self, first, members, color)
      type(coloring_t), intent(inout) :: self
      integer(ip), intent(in) :: first(:), members(:)
      integer, intent(in) :: color(:)

      integer(ip), allocatable :: order(:), next(:)
      integer(ip) :: b, m
      integer :: c

      self%n_colors = max(0, maxval(color))
      allocate (self%ptr(self%n_colors + 1), next(self%n_colors), order(size(color)))
      self%ptr = 0
      do b = 1, size(color)
         if (color(b) > 0) self%ptr(color(b) + 1) = self%ptr(color(b) + 1) + 1
      end do
      self%ptr(1) = 1
      do c = 1, self%n_colors
         self%ptr(c + 1) = self%ptr(c) + self%ptr(c + 1)
      end do
      next = self%ptr(1:self%n_colors)
      do b = 1, size(color)
         if (color(b) == 0) cycle
         order(next(color(b))) = b
         next(color(b)) = next(color(b)) + 1
      end do
      allocate (self%block_ptr(self%ptr(self%n_colors + 1)), self%vertices(size(members)))
      self%block_ptr(1) = 1
      do m = 1, self%ptr(self%n_colors + 1) - 1
         b = order(m)
         self%block_ptr(m + 1) = self%block_ptr(m) + first(b + 1) - first(b)
         self%vertices(self%block_ptr(m):self%block_ptr(m + 1) - 1) = members(first(b):first(b + 1) - 1)
      end do
   end subroutine group_by_color
end module twomem_estimate_coloring
