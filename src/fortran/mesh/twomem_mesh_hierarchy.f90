!> The nested hierarchy T_0 ⊂ T_1 ⊂ … ⊂ T_L made by uniform red refinement. Each refinement
!> keeps the coarse vertices first and in order, then adds one vertex per coarse edge at its
!> midpoint, and splits each triangle into four children numbered 4(t-1)+1..4t. Boundary
!> midpoints stay on the boundary chord, so the meshes are geometrically nested: a coarse P1
!> function is exactly representable on every finer level, which nested iteration and the
!> multilevel algebraic flux rely on. Prolongation is therefore just midpoint averaging.
module twomem_mesh_hierarchy
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t, signed_area, corner_of, position_of
   implicit none
   private

   public :: mesh_hierarchy_t, refinement_map_t, refine_red, red_children, parent_triangle

   !> How level l was made from level l-1.
   type :: refinement_map_t
      !> the two coarse vertices whose mean is fine vertex a (equal for an inherited vertex),
      !> (2, nv_fine)
      integer(ip), allocatable :: vertex_parents(:, :)
      ! (the coarse triangle of a fine one needs no table: parent_triangle)
   end type refinement_map_t

   type :: mesh_hierarchy_t
      integer :: levels = 0
      !> meshes(0) is the coarse mesh, meshes(levels) the finest
      type(mesh_t), allocatable :: meshes(:)
      !> maps(l) relates level l to level l-1, l = 1..levels
      type(refinement_map_t), allocatable :: maps(:)
   contains
      procedure :: init => hierarchy_init
      procedure :: free => hierarchy_free
      procedure :: prolong
      procedure :: first_with_unknowns
   end type mesh_hierarchy_t

contains

   !> Refine `coarse` `levels` times; the coarse mesh is copied into level 0.
   subroutine hierarchy_init(self, coarse, levels, err)
      class(mesh_hierarchy_t), intent(inout) :: self
      type(mesh_t), intent(in) :: coarse
      integer, intent(in) :: levels
      type(error_t), allocatable, intent(out) :: err

      integer :: l

      call self%free()
      self%levels = levels
      allocate (self%meshes(0:levels), self%maps(levels))
      self%meshes(0) = coarse
      do l = 1, levels
         call refine_red(self%meshes(l - 1), self%meshes(l), self%maps(l), err)
         if (allocated(err)) return
      end do
   end subroutine hierarchy_init

   subroutine hierarchy_free(self)
      class(mesh_hierarchy_t), intent(inout) :: self

      if (allocated(self%meshes)) deallocate (self%meshes)
      if (allocated(self%maps)) deallocate (self%maps)
      self%levels = 0
   end subroutine hierarchy_free

   !> Interpolate nodal values of a P1 function from level l-1 to level l (exact, since the
   !> spaces are nested).
   subroutine prolong(self, level, coarse_values, fine_values)
      class(mesh_hierarchy_t), intent(in) :: self
      integer, intent(in) :: level
      real(dp), intent(in) :: coarse_values(:)
      real(dp), intent(out) :: fine_values(:)

      integer(ip) :: a

      associate (p => self%maps(level)%vertex_parents)
         do a = 1, size(fine_values, kind=ip)
            fine_values(a) = 0.5_dp*(coarse_values(p(1, a)) + coarse_values(p(2, a)))
         end do
      end associate
   end subroutine prolong

   !> The first level with an interior vertex on some rank of `comm` (levels when none has):
   !> below it the boundary values decide everything, so there is nothing to solve, to coarsen
   !> to or to take as a coarse problem (a Gmsh mesh of a few triangles). Collective.
   integer function first_with_unknowns(self, comm) result(level)
      class(mesh_hierarchy_t), intent(in) :: self
      type(comm_t), intent(in) :: comm

      do level = 0, self%levels - 1
         if (comm%any_true(any(.not. self%meshes(level)%boundary_vertex))) return
      end do
      level = self%levels
   end function first_with_unknowns

   !> The red refinement of `coarse`, with everything `mesh_t%init` would derive built directly
   !> from the parent in parallel loops: children of a valid mesh are valid (counter-clockwise,
   !> conforming, none degenerate), so there is nothing to check and nothing to search. New
   !> vertex nv_c + e is the midpoint of coarse edge e; coarse edge e = (a, b) splits into edges
   !> 2e − 1 = (a, m) and 2e = (b, m); the three edges inside coarse triangle t follow, the one
   !> opposite its corner i numbered 2 ne_c + 3(t − 1) + i. Patches list triangles in ascending
   !> order, as `mesh_t%init` does, so assembly sums in the same order on every mesh.
   subroutine refine_red(coarse, fine, map, err)
      type(mesh_t), intent(in) :: coarse
      type(mesh_t), intent(inout) :: fine
      type(refinement_map_t), intent(out) :: map
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: nvc, nec, ntc, a, e, t, i, k, m(3), v(3), child
      integer(ip) :: half(3, 3)

      call fine%free()
      nvc = coarse%nv
      nec = coarse%ne
      ntc = coarse%nt
      fine%nv = nvc + nec
      fine%nt = 4*ntc
      fine%ne = 2*nec + 3*ntc
      fine%diameter = coarse%diameter
      fine%n_flipped = 0
      allocate (fine%vertices(2, fine%nv), fine%triangles(3, fine%nt), fine%edges(2, fine%ne), &
                fine%triangle_edges(3, fine%nt), fine%edge_triangles(2, fine%ne), fine%boundary_vertex(fine%nv), &
                fine%boundary_edge(fine%ne), fine%area(fine%nt))
      allocate (map%vertex_parents(2, fine%nv))

      !$omp parallel default(none) shared(coarse, fine, map, nvc, nec, ntc) private(a, e, t, i, k, m, v, child, half)
      !$omp do schedule(static)
      do a = 1, nvc
         fine%vertices(:, a) = coarse%vertices(:, a)
         fine%boundary_vertex(a) = coarse%boundary_vertex(a)
         map%vertex_parents(:, a) = a
      end do
      !$omp end do nowait
      !$omp do schedule(static)
      do e = 1, nec
         associate (ends => coarse%edges(:, e))
            fine%vertices(:, nvc + e) = 0.5_dp*(coarse%vertices(:, ends(1)) + coarse%vertices(:, ends(2)))
            fine%boundary_vertex(nvc + e) = coarse%boundary_edge(e)
            map%vertex_parents(:, nvc + e) = ends
            fine%edges(:, 2*e - 1) = [ends(1), nvc + e]
            fine%edges(:, 2*e) = [ends(2), nvc + e]
            fine%boundary_edge(2*e - 1:2*e) = coarse%boundary_edge(e)
            ! the children at each end of the edge, on either side of it
            do k = 1, 2
               t = coarse%edge_triangles(k, e)
               if (t == 0) then
                  fine%edge_triangles(k, 2*e - 1:2*e) = 0
               else
                  fine%edge_triangles(k, 2*e - 1) = 4*(t - 1) + corner_of(coarse, t, ends(1))
                  fine%edge_triangles(k, 2*e) = 4*(t - 1) + corner_of(coarse, t, ends(2))
               end if
            end do
         end associate
      end do
      ! a barrier: the triangle loop measures children, so it needs every vertex set
      !$omp end do
      !$omp do schedule(static)
      do t = 1, ntc
         v = coarse%triangles(:, t)
         ! m(i) is the midpoint of the edge opposite vertex i
         m = nvc + coarse%triangle_edges(:, t)
         fine%triangles(:, 4*t - 3) = [v(1), m(3), m(2)]
         fine%triangles(:, 4*t - 2) = [m(3), v(2), m(1)]
         fine%triangles(:, 4*t - 1) = [m(2), m(1), v(3)]
         fine%triangles(:, 4*t) = [m(1), m(2), m(3)]
         ! half(j, i): the fine half of the coarse edge opposite corner j that touches corner i
         do i = 1, 3
            do k = 1, 3
               if (k == i) cycle
               e = coarse%triangle_edges(k, t)
               half(k, i) = merge(2*e - 1, 2*e, coarse%edges(1, e) == v(i))
            end do
         end do
         ! inner edge opposite corner i: between the other two midpoints; child i and the middle one
         do i = 1, 3
            e = 2*nec + 3*(t - 1) + i
            associate (p => m(modulo(i, 3) + 1), q => m(modulo(i + 1, 3) + 1))
               fine%edges(:, e) = [min(p, q), max(p, q)]
            end associate
            fine%boundary_edge(e) = .false.
            fine%edge_triangles(:, e) = [4*(t - 1) + i, 4*t]
         end do
         child = 4*t - 3
         fine%triangle_edges(:, child) = [2*nec + 3*(t - 1) + 1, half(2, 1), half(3, 1)]
         child = 4*t - 2
         fine%triangle_edges(:, child) = [half(1, 2), 2*nec + 3*(t - 1) + 2, half(3, 2)]
         child = 4*t - 1
         fine%triangle_edges(:, child) = [half(1, 3), half(2, 3), 2*nec + 3*(t - 1) + 3]
         fine%triangle_edges(:, 4*t) = 2*nec + 3*(t - 1) + [1, 2, 3]
         do k = 4*t - 3, 4*t
            call measure(fine, k)
         end do
      end do
      !$omp end do
      !$omp end parallel
      call refined_patches(coarse, fine)
      call refined_partition(coarse, fine)
   end subroutine refine_red

   !> The partition data of the children: each inherits its parent's owner and gets its number
   !> in the refined whole mesh, which the serial numbering fixes (see `refine_red`): vertex
   !> nv + e for the midpoint of whole-mesh edge e, triangle 4(t − 1) + c, edges 2e − 1, 2e
   !> (the half at the lower-numbered end first) and 2 ne + 3(t − 1) + i.
   subroutine refined_partition(coarse, fine)
      type(mesh_t), intent(in) :: coarse
      type(mesh_t), intent(inout) :: fine

      integer(ip) :: nvc, nec, e, t, i, ge, gt
      integer :: k

      nvc = coarse%nv
      nec = coarse%ne
      fine%nt_owned = 4*coarse%nt_owned
      fine%nv_global = coarse%nv_global + coarse%ne_global
      fine%nt_global = 4*coarse%nt_global
      fine%ne_global = 2*coarse%ne_global + 3*coarse%nt_global
      ! the children of a whole mesh are numbered as a whole mesh's
      if (coarse%whole()) return
      allocate (fine%global_vertex(fine%nv), fine%global_triangle(fine%nt), fine%global_edge(fine%ne), &
                fine%triangle_owner(fine%nt), fine%vertex_owner(fine%nv))
      !$omp parallel default(none) shared(coarse, fine, nvc, nec) private(e, t, i, ge, gt, k)
      !$omp do schedule(static)
      do i = 1, nvc
         fine%global_vertex(i) = coarse%global_vertex(i)
         fine%vertex_owner(i) = coarse%vertex_owner(i)
      end do
      !$omp end do nowait
      !$omp do schedule(static)
      do e = 1, nec
         ge = coarse%global_edge(e)
         fine%global_vertex(nvc + e) = coarse%nv_global + ge
         ! the midpoint's triangles are children of the triangles beside the edge (the owner
         ! is exact where the local mesh holds both, as around every vertex of an own triangle)
         fine%vertex_owner(nvc + e) = huge(1)
         do k = 1, 2
            t = coarse%edge_triangles(k, e)
            if (t > 0) fine%vertex_owner(nvc + e) = min(fine%vertex_owner(nvc + e), coarse%triangle_owner(t))
         end do
         if (coarse%global_vertex(coarse%edges(1, e)) < coarse%global_vertex(coarse%edges(2, e))) then
            fine%global_edge(2*e - 1) = 2*ge - 1
            fine%global_edge(2*e) = 2*ge
         else
            fine%global_edge(2*e - 1) = 2*ge
            fine%global_edge(2*e) = 2*ge - 1
         end if
      end do
      !$omp end do nowait
      !$omp do schedule(static)
      do t = 1, coarse%nt
         gt = coarse%global_triangle(t)
         do k = 1, 4
            fine%global_triangle(4*(t - 1) + k) = 4*(gt - 1) + k
            fine%triangle_owner(4*(t - 1) + k) = coarse%triangle_owner(t)
         end do
         do i = 1, 3
            fine%global_edge(2*nec + 3*(t - 1) + i) = 2*coarse%ne_global + 3*(gt - 1) + i
         end do
      end do
      !$omp end do
      !$omp end parallel
   end subroutine refined_partition

   !> Area of triangle t, computed as `mesh_t%init` computes it.
   subroutine measure(mesh, t)
      type(mesh_t), intent(inout) :: mesh
      integer(ip), intent(in) :: t

      associate (v => mesh%triangles(:, t))
         mesh%area(t) = abs(signed_area(mesh%vertices(:, v(1)), mesh%vertices(:, v(2)), mesh%vertices(:, v(3))))
      end associate
   end subroutine measure

   !> The fine patches: a coarse vertex keeps its coarse patch's corner children; an edge
   !> midpoint gets the three children of each coarse triangle beside the edge that touch it.
   subroutine refined_patches(coarse, fine)
      type(mesh_t), intent(in) :: coarse
      type(mesh_t), intent(inout) :: fine

      integer(ip) :: a, e, k, t, j, n, fill, list(6), key
      integer :: q, p

      allocate (fine%patch_ptr(fine%nv + 1))
      fine%patch_ptr(1) = 1
      do a = 1, coarse%nv
         fine%patch_ptr(a + 1) = coarse%patch_ptr(a + 1) - coarse%patch_ptr(a)
      end do
      do e = 1, coarse%ne
         ! three children on each side of the edge that the local mesh holds
         fine%patch_ptr(coarse%nv + e + 1) = merge(3, 6, coarse%edge_triangles(2, e) == 0)
      end do
      do a = 1, fine%nv
         fine%patch_ptr(a + 1) = fine%patch_ptr(a + 1) + fine%patch_ptr(a)
      end do
      allocate (fine%patch_triangles(fine%patch_ptr(fine%nv + 1) - 1))
      !$omp parallel default(none) shared(coarse, fine) private(a, e, k, t, j, n, fill, list, key, q, p)
      !$omp do schedule(static)
      do a = 1, coarse%nv
         fill = fine%patch_ptr(a)
         do k = coarse%patch_ptr(a), coarse%patch_ptr(a + 1) - 1
            t = coarse%patch_triangles(k)
            fine%patch_triangles(fill) = 4*(t - 1) + corner_of(coarse, t, a)
            fill = fill + 1
         end do
      end do
      !$omp end do nowait
      !$omp do schedule(static)
      do e = 1, coarse%ne
         n = 0
         do k = 1, 2
            t = coarse%edge_triangles(k, e)
            if (t == 0) cycle
            ! the edge is opposite corner j of t: the other two corner children and the middle one
            j = position_of(coarse%triangle_edges(:, t), e)
            list(n + 1:n + 3) = [4*(t - 1) + modulo(j, 3) + 1, 4*(t - 1) + modulo(j + 1, 3) + 1, 4*t]
            n = n + 3
         end do
         do q = 2, n
            key = list(q)
            p = q - 1
            do while (p >= 1)
               if (list(p) <= key) exit
               list(p + 1) = list(p)
               p = p - 1
            end do
            list(p + 1) = key
         end do
         fine%patch_triangles(fine%patch_ptr(coarse%nv + e):fine%patch_ptr(coarse%nv + e + 1) - 1) = list(1:n)
      end do
      !$omp end do
      !$omp end parallel
   end subroutine refined_patches
   !> The corners of the four children of the triangle with corners v, numbered and ordered as
   !> refine_red makes them; m_i is the midpoint of the edge opposite corner i.
   !> The coarse triangle that fine triangle t lies in: refine_red numbers the children of coarse
   !> triangle T as 4T − 3 .. 4T.
   elemental integer(ip) function parent_triangle(t)
      integer(ip), intent(in) :: t

      parent_triangle = (t - 1)/4 + 1
   end function parent_triangle

   pure function red_children(v) result(children)
      real(dp), intent(in) :: v(2, 3)
      real(dp) :: children(2, 3, 4)

      real(dp) :: m(2, 3)

      m(:, 1) = 0.5_dp*(v(:, 2) + v(:, 3))
      m(:, 2) = 0.5_dp*(v(:, 3) + v(:, 1))
      m(:, 3) = 0.5_dp*(v(:, 1) + v(:, 2))
      children(:, :, 1) = reshape([v(:, 1), m(:, 3), m(:, 2)], [2, 3])
      children(:, :, 2) = reshape([m(:, 3), v(:, 2), m(:, 1)], [2, 3])
      children(:, :, 3) = reshape([m(:, 2), m(:, 1), v(:, 3)], [2, 3])
      children(:, :, 4) = m
   end function red_children
end module twomem_mesh_hierarchy
