!> Transfer between consecutive levels of the nested hierarchy, restricted to the unknowns of
!> the discrete problem (interior vertices, numbered for locality: `interior_numbering`). The
!> prolongation P_l maps
!> a P1 function of level l−1 that vanishes on ∂Ω to level l exactly: an inherited vertex
!> copies its value, a new vertex (an edge midpoint) takes the mean of the edge's ends, and
!> boundary ends contribute zero. These matrices, with the interface of each level's unknowns
!> in a distributed run, are all the multigrid preconditioner knows of the geometry.
module twomem_fem_transfer
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_base_comm, only: comm_t
   use twomem_base_sort, only: sorting_permutation
   implicit none
   private

   public :: interior_numbering, interior_vertices, interior_prolongation, interior_prolongations, interior_halo

contains

   !> unknown(a): the number of vertex a among the interior vertices, 0 on ∂Ω and, on a rank's
   !> piece of a distributed mesh, at vertices of its ghost layer only. The unknowns go in the
   !> order of their vertex's first triangle (mesh_t%vertices_by_first_triangle), not in vertex
   !> order: red refinement numbers the midpoints of a level after all the vertices of the level
   !> below, so in vertex order every matrix row reaches into two distant ranges of a vector, and
   !> above the cache's size each sparse product waited on memory. Along the triangles' tree a
   !> row's neighbours are numbered close to it (docs/performance.md has a benchmark of both
   !> orders).
   function interior_numbering(mesh) result(unknown)
      type(mesh_t), intent(in) :: mesh
      integer(ip), allocatable :: unknown(:)

      integer(ip), allocatable :: order(:)
      integer(ip) :: a, k, n
      logical, allocatable :: inside(:)

      allocate (unknown(mesh%nv))
      inside = mesh%in_subdomain()
      order = mesh%vertices_by_first_triangle()
      n = 0
      do k = 1, mesh%nv
         a = order(k)
         if (mesh%boundary_vertex(a) .or. .not. inside(a)) then
            unknown(a) = 0
         else
            n = n + 1
            unknown(a) = n
         end if
      end do
   end function interior_numbering

   !> interior(i): the vertex of unknown i of the numbering `unknown` (its inverse).
   pure function interior_vertices(unknown) result(interior)
      integer(ip), intent(in) :: unknown(:)
      integer(ip), allocatable :: interior(:)

      integer(ip) :: a

      allocate (interior(count(unknown > 0, kind=ip)))
      do a = 1, size(unknown, kind=ip)
         if (unknown(a) > 0) interior(unknown(a)) = a
      end do
   end function interior_vertices

   !> P_l from level l−1 to level l of `hierarchy` (l ≥ 1), on interior unknowns.
   function interior_prolongation(hierarchy, l) result(p)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: l
      type(csr_t) :: p

      p = prolongation_between(hierarchy, l, interior_numbering(hierarchy%meshes(l)), &
                               interior_numbering(hierarchy%meshes(l - 1)))
   end function interior_prolongation

   !> P_l for the numberings `fine` of level l and `coarse` of level l − 1 (interior_numbering).
   function prolongation_between(hierarchy, l, fine, coarse) result(p)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: l
      integer(ip), intent(in) :: fine(:), coarse(:)
      type(csr_t) :: p

      integer(ip), allocatable :: row_ptr(:), col(:)
      real(dp), allocatable :: val(:)
      integer(ip) :: a, k, nf, nnz, m

      nf = maxval(fine)
      ! rows in unknown order, which is not vertex order: each row's length first
      allocate (row_ptr(nf + 1), col(2*nf), val(2*nf))
      row_ptr = 0
      associate (parents => hierarchy%maps(l)%vertex_parents)
         do a = 1, hierarchy%meshes(l)%nv
            if (fine(a) == 0) cycle
            if (parents(1, a) == parents(2, a)) then
               row_ptr(fine(a) + 1) = 1
            else
               row_ptr(fine(a) + 1) = count(coarse(parents(:, a)) > 0)
            end if
         end do
         row_ptr(1) = 1
         do m = 1, nf
            row_ptr(m + 1) = row_ptr(m + 1) + row_ptr(m)
         end do
         nnz = row_ptr(nf + 1) - 1
         do a = 1, hierarchy%meshes(l)%nv
            if (fine(a) == 0) cycle
            m = row_ptr(fine(a))
            if (parents(1, a) == parents(2, a)) then
               col(m) = coarse(parents(1, a))
               val(m) = 1.0_dp
            else
               do k = 1, 2
                  if (coarse(parents(k, a)) == 0) cycle
                  col(m) = coarse(parents(k, a))
                  val(m) = 0.5_dp
                  m = m + 1
               end do
            end if
         end do
      end associate
      call p%init_pattern(row_ptr, col(1:nnz), ncol=maxval(coarse))
      ! sorting may swap the two entries of a midpoint row, which are equal: values keep their place
      p%val = val(1:nnz)
   end function prolongation_between

   !> P_1 .. P_L for levels 0..L of `hierarchy` (L = `finest`), each level's numbering made once.
   function interior_prolongations(hierarchy, finest) result(p)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: finest
      type(csr_t), allocatable :: p(:)

      integer(ip), allocatable :: fine(:), coarse(:)
      integer :: l

      allocate (p(finest))
      if (finest > 0) coarse = interior_numbering(hierarchy%meshes(0))
      do l = 1, finest
         fine = interior_numbering(hierarchy%meshes(l))
         p(l) = prolongation_between(hierarchy, l, fine, coarse)
         call move_alloc(fine, coarse)
      end do
   end function interior_prolongations
   !> The interface of the unknowns at vertices `interior` of a rank's piece of a distributed
   !> mesh: which neighbours share each one (the owners of the triangles at its vertex, whose whole
   !> patch is local), lists ordered by whole-mesh vertex number, and who owns it.
   subroutine interior_halo(mesh, interior, comm, halo)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: interior(:)
      type(comm_t), intent(in) :: comm
      type(halo_t), intent(out) :: halo

      logical, allocatable :: shares(:, :)
      integer, allocatable :: neighbours(:), ptr(:), owner(:)
      integer(ip), allocatable :: idx(:), order(:)
      integer(ip) :: i, m, a
      integer :: q, k, fill

      allocate (shares(size(interior), 0:comm%size - 1))
      shares = .false.
      do i = 1, size(interior)
         a = interior(i)
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            q = mesh%triangle_owner_of(mesh%patch_triangles(m))
            if (q /= comm%rank) shares(i, q) = .true.
         end do
      end do
      neighbours = pack([(q, q=0, comm%size - 1)], any(shares, dim=1))
      allocate (ptr(size(neighbours) + 1))
      ptr(1) = 1
      do k = 1, size(neighbours)
         ptr(k + 1) = ptr(k) + count(shares(:, neighbours(k)))
      end do
      ! unknowns in whole-mesh order: both sides of an interface list it alike (with no
      ! neighbour there is nothing to list, and a serial run skips a heap sort of every unknown)
      if (size(neighbours) > 0) then
         order = sorting_permutation(mesh%global_vertex_of(interior))
      else
         allocate (order(0))
      end if
      allocate (idx(ptr(size(neighbours) + 1) - 1))
      do k = 1, size(neighbours)
         fill = ptr(k)
         do m = 1, size(order)
            if (shares(order(m), neighbours(k))) then
               idx(fill) = order(m)
               fill = fill + 1
            end if
         end do
      end do
      owner = mesh%vertex_owner_of(interior)
      call halo%init(comm, owner, neighbours, ptr, idx)
   end subroutine interior_halo


end module twomem_fem_transfer
