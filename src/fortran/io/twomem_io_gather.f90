!> Distributed results in the serial layout: each rank sends the vertices and triangles it
!> owns, tagged with their whole-mesh numbers, and rank 0 puts every value in its place. The
!> result file of a distributed run is therefore the file a one-rank run writes (same order,
!> same datasets), written by rank 0 alone. Its size limit is rank 0's memory: the whole
!> finest mesh and its fields, about 100 bytes per vertex without estimators and 260 with.
module twomem_io_gather
   use twomem_base_kinds, only: dp, ip
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_linalg_vectors, only: threaded_from
   implicit none
   private

   public :: gather_plan_t

   !> Which local vertices and triangles this rank contributes, and (rank 0) where every
   !> contribution goes in the whole arrays.
   type :: gather_plan_t
      type(comm_t) :: comm
      integer(ip) :: nv = 0, nt = 0
      integer(ip), allocatable :: my_vertices(:), my_triangles(:)
      integer, allocatable :: vertex_counts(:), triangle_counts(:)
      integer(ip), allocatable :: vertex_slots(:), triangle_slots(:)
   contains
      procedure :: init
      procedure :: nodal
      procedure :: cells
      procedure :: mesh_arrays
   end type gather_plan_t

contains

   !> The plan for `mesh` (this rank's piece of the finest mesh). Collective.
   subroutine init(self, comm, mesh)
      class(gather_plan_t), intent(out) :: self
      type(comm_t), intent(in) :: comm
      type(mesh_t), intent(in) :: mesh

      logical, allocatable :: inside(:)
      integer(ip) :: a

      self%comm = comm
      self%nv = mesh%nv_global
      self%nt = mesh%nt_global
      inside = mesh%in_subdomain()
      self%my_vertices = pack([(a, a=1, mesh%nv)], inside .and. mesh%vertex_owner_of([(a, a=1, mesh%nv)]) == comm%rank)
      self%my_triangles = [(a, a=1, mesh%nt_owned)]
      call comm%gather_counts(size(self%my_vertices), self%vertex_counts)
      call comm%gather_counts(size(self%my_triangles), self%triangle_counts)
      allocate (self%vertex_slots(merge(sum(self%vertex_counts), 0, comm%is_root())), &
                self%triangle_slots(merge(sum(self%triangle_counts), 0, comm%is_root())))
      call comm%gatherv(mesh%global_vertex_of(self%my_vertices), self%vertex_counts, self%vertex_slots)
      call comm%gatherv(mesh%global_triangle_of(self%my_triangles), self%triangle_counts, self%triangle_slots)
   end subroutine init

   !> The whole nodal field (rank 0; empty elsewhere) from this rank's nodal values. Collective.
   function nodal(self, values) result(whole)
      class(gather_plan_t), intent(in) :: self
      real(dp), intent(in) :: values(:)
      real(dp), allocatable :: whole(:)

      allocate (whole(merge(self%nv, 0_ip, self%comm%is_root())))
      call gather_reals(self, values, self%my_vertices, self%vertex_counts, self%vertex_slots, whole)
   end function nodal

   !> The whole per-triangle field (rank 0) from this rank's values on its triangles. Collective.
   function cells(self, values) result(whole)
      class(gather_plan_t), intent(in) :: self
      real(dp), intent(in) :: values(:)
      real(dp), allocatable :: whole(:)

      allocate (whole(merge(self%nt, 0_ip, self%comm%is_root())))
      call gather_reals(self, values, self%my_triangles, self%triangle_counts, self%triangle_slots, whole)
   end function cells

   !> whole(slots) on rank 0 = every rank's values(mine), in rank order. One rank moves each
   !> value straight to its place, threaded: copies through a gathered buffer, made by one
   !> thread, were a visible part of writing the result at millions of vertices. Collective.
   subroutine gather_reals(self, values, mine, counts, slots, whole)
      type(gather_plan_t), intent(in) :: self
      real(dp), intent(in) :: values(:)
      integer(ip), intent(in) :: mine(:), slots(:)
      integer, intent(in) :: counts(:)
      real(dp), intent(inout) :: whole(:)

      real(dp), allocatable :: gathered(:)
      integer(ip) :: i

      if (self%comm%size == 1) then
         !$omp parallel do default(none) shared(whole, slots, values, mine) private(i) schedule(static) &
         !$omp if(size(mine) > threaded_from)
         do i = 1, size(mine, kind=ip)
            whole(slots(i)) = values(mine(i))
         end do
         !$omp end parallel do
         return
      end if
      allocate (gathered(size(slots)))
      call self%comm%gatherv(values(mine), counts, gathered)
      if (self%comm%is_root()) whole(slots) = gathered
   end subroutine gather_reals

   !> The whole mesh's vertices (2, nv) and triangles (3, nt) on rank 0. Collective.
   subroutine mesh_arrays(self, mesh, vertices, triangles)
      class(gather_plan_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      real(dp), allocatable, intent(out) :: vertices(:, :)
      integer(ip), allocatable, intent(out) :: triangles(:, :)

      real(dp), allocatable :: x(:), y(:)
      integer(ip), allocatable :: corner(:), gathered(:)
      integer :: k

      x = self%nodal(mesh%vertices(1, :))
      y = self%nodal(mesh%vertices(2, :))
      allocate (vertices(2, size(x)), triangles(3, merge(self%nt, 0_ip, self%comm%is_root())))
      vertices(1, :) = x
      vertices(2, :) = y
      allocate (gathered(size(self%triangle_slots)))
      do k = 1, 3
         corner = mesh%global_vertex_of(mesh%triangles(k, self%my_triangles))
         call self%comm%gatherv(corner, self%triangle_counts, gathered)
         if (self%comm%is_root()) triangles(k, self%triangle_slots) = gathered
      end do
   end subroutine mesh_arrays
end module twomem_io_gather
