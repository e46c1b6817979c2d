!> How a distributed run splits the coarse mesh: rank 0 partitions its triangles with METIS
!> (through the dual graph, so parts are compact and their interfaces short) and broadcasts
!> the partition; every rank then keeps its own triangles plus the ghost layer (the other
!> ranks' triangles that share a vertex with its own), renumbers them locally (own triangles
!> first) and records for every local vertex, edge and triangle its number in the whole mesh
!> and its owner. Each rank refines its piece itself (`refine_red` carries the partition to
!> the children), so the hierarchy is nested per rank and no rank ever holds a fine mesh it does
!> not own. The whole coarse mesh is known on every rank (it is small, and made identically
!> everywhere or broadcast from rank 0), so the extraction needs no further communication.
!> One rank's piece is the whole mesh itself. A file's mesh that the reader numbered along the
!> domain (twomem_mesh_gmsh) gets the file's numbers as its pieces' whole-mesh numbers
!> (`number_as_file`), so that the result is written in them.
module twomem_mesh_partition
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_base_text, only: int_text
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t, corner_of
   use twomem_mesh_metis, only: metis_partition
   implicit none
   private

   public :: distribute_coarse, share_mesh, number_as_file

contains

   !> Make rank 0's `mesh` (a whole mesh) the mesh of every rank.
   subroutine share_mesh(comm, mesh, source, err)
      type(comm_t), intent(in) :: comm
      type(mesh_t), intent(inout) :: mesh
      character(len=*), intent(in) :: source
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      real(dp), allocatable :: diameter(:)

      if (comm%size == 1) return
      if (comm%is_root()) then
         vertices = mesh%vertices
         triangles = mesh%triangles
         diameter = [mesh%diameter]
      end if
      call comm%bcast(vertices)
      call comm%bcast(triangles)
      call comm%bcast(diameter)
      if (.not. comm%is_root()) call mesh%init(vertices, triangles, source, err, diameter=diameter(1))
   end subroutine share_mesh

   !> This rank's piece of the whole coarse mesh `whole` (identical on every rank), in
   !> whole-mesh order.
   subroutine distribute_coarse(comm, whole, local, err)
      type(comm_t), intent(in) :: comm
      type(mesh_t), intent(in) :: whole
      type(mesh_t), intent(inout) :: local
      type(error_t), allocatable, intent(out) :: err

      integer(ip), allocatable :: part(:), tri_local(:), vert_local(:), triangles(:, :)
      integer, allocatable :: owner(:)
      logical, allocatable :: own_vertex(:), keep(:)
      real(dp), allocatable :: vertices(:, :)
      integer(ip) :: t, a, m, i, nt, nv, nt_own

      if (comm%size == 1) then
         ! one rank's piece is the whole mesh as it is (made again from its arrays, a mesh of 10⁶
         ! vertices took half a second)
         local = whole
         call local%set_whole()
         return
      end if

      allocate (part(whole%nt))
      if (comm%is_root()) call metis_partition(whole%nv, whole%triangles, comm%size, part, err)
      call comm%agree(err)
      if (allocated(err)) return
      call comm%bcast(part)
      ! a rank without triangles would have no unknowns of its own: refuse, rather than run
      ! with idle ranks or fail later in a confusing place
      if (count(part == comm%rank) == 0) then
         call make_error(err, exit_bad_input, 'mesh', 'the coarse mesh has '//int_text(int(whole%nt))// &
                         ' triangles, too few to give each of '//int_text(comm%size)//' MPI ranks a part: '// &
                         'use fewer ranks or a finer coarse mesh (mesh.coarse_h)')
      end if
      call comm%agree(err)
      if (allocated(err)) return

      allocate (owner(whole%nv), own_vertex(whole%nv), keep(whole%nt))
      ! owner of a vertex: the lowest rank owning a triangle at it
      do a = 1, whole%nv
         owner(a) = huge(1)
         do m = whole%patch_ptr(a), whole%patch_ptr(a + 1) - 1
            owner(a) = min(owner(a), part(whole%patch_triangles(m)))
         end do
      end do
      own_vertex = .false.
      do t = 1, whole%nt
         if (part(t) == comm%rank) own_vertex(whole%triangles(:, t)) = .true.
      end do
      ! own triangles, then the ghost layer: other triangles at a vertex of an own one
      do t = 1, whole%nt
         keep(t) = part(t) == comm%rank .or. any(own_vertex(whole%triangles(:, t)))
      end do
      nt_own = count(part == comm%rank, kind=ip)
      nt = count(keep, kind=ip)
      allocate (tri_local(nt), vert_local(whole%nv))
      i = 0
      do t = 1, whole%nt
         if (part(t) == comm%rank) then
            i = i + 1
            tri_local(i) = t
         end if
      end do
      do t = 1, whole%nt
         if (keep(t) .and. part(t) /= comm%rank) then
            i = i + 1
            tri_local(i) = t
         end if
      end do
      ! local vertices in whole-mesh order
      vert_local = 0
      do i = 1, nt
         vert_local(whole%triangles(:, tri_local(i))) = 1
      end do
      nv = 0
      do a = 1, whole%nv
         if (vert_local(a) > 0) then
            nv = nv + 1
            vert_local(a) = nv
         end if
      end do
      allocate (triangles(3, nt))
      do i = 1, nt
         triangles(:, i) = vert_local(whole%triangles(:, tri_local(i)))
      end do
      allocate (vertices(2, nv))
      do a = 1, whole%nv
         if (vert_local(a) > 0) vertices(:, vert_local(a)) = whole%vertices(:, a)
      end do
      call local%init(vertices, triangles, 'partition', err, diameter=whole%diameter)
      if (allocated(err)) return
      call attach_partition(whole, tri_local, vert_local, part, owner, nt_own, local)
   end subroutine distribute_coarse

   !> The whole-mesh numbers of `piece` (distribute_coarse's) made those of a file whose mesh
   !> was renumbered before it became the whole mesh: file_vertex(a) and file_triangle(t) are
   !> the file's numbers of the whole mesh's vertex a and triangle t. A whole mesh (one rank's
   !> piece) becomes a piece of itself that owns everything, so that the result and the loads
   !> keep the file's numbering.
   subroutine number_as_file(piece, file_vertex, file_triangle)
      type(mesh_t), intent(inout) :: piece
      integer(ip), intent(in) :: file_vertex(:), file_triangle(:)

      integer(ip) :: e

      if (piece%whole()) then
         piece%global_vertex = file_vertex
         piece%global_triangle = file_triangle
         piece%global_edge = [(e, e=1, piece%ne)]
         allocate (piece%vertex_owner(piece%nv), piece%triangle_owner(piece%nt))
         piece%vertex_owner = 0
         piece%triangle_owner = 0
      else
         piece%global_vertex = file_vertex(piece%global_vertex)
         piece%global_triangle = file_triangle(piece%global_triangle)
      end if
   end subroutine number_as_file

   !> The partition data of the piece: whole-mesh numbers, owners, and the boundary as the
   !> whole mesh has it (the piece's own outline is not the domain's boundary).
   subroutine attach_partition(whole, tri_local, vert_local, part, owner, nt_own, local)
      type(mesh_t), intent(in) :: whole
      integer(ip), intent(in) :: tri_local(:), vert_local(:), part(:)
      integer, intent(in) :: owner(:)
      integer(ip), intent(in) :: nt_own
      type(mesh_t), intent(inout) :: local

      integer(ip) :: e, i, a
      integer :: j

      local%nt_owned = nt_own
      local%nv_global = whole%nv
      local%nt_global = whole%nt
      local%ne_global = whole%ne
      local%global_triangle = tri_local
      local%triangle_owner = part(tri_local)
      allocate (local%global_vertex(local%nv), local%vertex_owner(local%nv), local%global_edge(local%ne))
      do a = 1, whole%nv
         if (vert_local(a) > 0) then
            local%global_vertex(vert_local(a)) = a
            local%vertex_owner(vert_local(a)) = owner(a)
            local%boundary_vertex(vert_local(a)) = whole%boundary_vertex(a)
         end if
      end do
      ! a local triangle has its whole triangle's vertices in the same order (the whole mesh's
      ! triangles are counter-clockwise already, so mesh_t%init flipped none), so the edge opposite
      ! its local vertex j is the whole triangle's: one pass over the triangles, not a search per edge
      do i = 1, local%nt
         do j = 1, 3
            local%global_edge(local%triangle_edges(j, i)) = whole%triangle_edges(j, tri_local(i))
         end do
      end do
      do e = 1, local%ne
         local%boundary_edge(e) = whole%boundary_edge(local%global_edge(e))
      end do
   end subroutine attach_partition

end module twomem_mesh_partition
