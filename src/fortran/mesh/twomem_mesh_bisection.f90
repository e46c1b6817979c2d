!> Newest-vertex bisection (Mitchell; Stevenson, Math. Comp. 77, 2008): local refinement that
!> keeps a mesh conforming, its successors nested and their shapes within finitely many
!> similarity classes per initial triangle. Every triangle lists its vertices counter-clockwise
!> with its newest vertex third, so that its refinement edge is the edge (v1, v2) opposite it.
!> Bisecting the triangle halves that edge at its midpoint m and makes the children (v3, v1, m)
!> and (v2, v3, m), whose newest vertex is m and whose refinement edges are the parent's other two
!> edges. A triangle whose other edge is halved (by a neighbour's refinement) must halve its
!> refinement edge first, which is the conforming closure: the edges to halve are the three
!> edges of every marked triangle, closed under "an edge of a triangle is halved ⇒ its
!> refinement edge is"; each triangle is then bisected once, twice or three times (its
!> children again where their refinement edges are halved). A marked triangle thus becomes
!> four children of a quarter of its area (two bisection generations, "bisec3" in the
!> literature's codes) rather than two: an adaptive step halves the mesh size where it marks
!> instead of dividing it by √2, so the adaptive loop reaches a given error in about half the
!> steps with meshes of the same size, and the sum over its steps costs less against the last
!> one (docs/performance.md). Closure, nesting and the finitely many similarity classes are
!> those of single bisection. New vertices are edge midpoints, numbered after the old ones in
!> edge order, so a P1 function prolongs by midpoint averaging (`refinement_map_t`, as for red
!> refinement). On the initial mesh the longest edge of each
!> triangle is its refinement edge, which keeps the closure short and the shapes regular.
module twomem_mesh_bisection
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: refinement_map_t
   implicit none
   private

   public :: longest_edge_first, bisect_marked

contains

   !> `mesh` with each triangle's vertices rotated (orientation kept) so that its longest edge
   !> is (v1, v2): the initial refinement edges.
   subroutine longest_edge_first(mesh, err)
      type(mesh_t), intent(inout) :: mesh
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      integer(ip) :: t
      integer :: k, longest
      real(dp) :: edge(3)
      real(dp) :: diameter

      triangles = mesh%triangles
      do t = 1, mesh%nt
         associate (v => triangles(:, t))
            ! edge k is opposite local vertex k
            do k = 1, 3
               edge(k) = norm2(mesh%vertices(:, v(mod(k, 3) + 1)) - mesh%vertices(:, v(mod(k + 1, 3) + 1)))
            end do
            longest = maxloc(edge, dim=1)
            ! the vertex opposite the longest edge goes third
            triangles(:, t) = cshift(triangles(:, t), longest - 3)
         end associate
      end do
      vertices = mesh%vertices
      diameter = mesh%diameter
      call mesh%init(vertices, triangles, 'bisection', err, diameter=diameter)
   end subroutine longest_edge_first

   !> `fine`: `coarse` with every marked triangle's three edges halved (four children) and the
   !> conforming closure, and how its vertices come from coarse's (map). coarse must hold its
   !> edge tables (triangle_edges, edges) and its triangles in newest-vertex order.
   subroutine bisect_marked(coarse, marked, fine, map, err)
      type(mesh_t), intent(in) :: coarse
      logical, intent(in) :: marked(:)
      type(mesh_t), intent(inout) :: fine
      type(refinement_map_t), intent(out) :: map
      type(error_t), allocatable, intent(out) :: err

      logical, allocatable :: halved(:)
      integer(ip), allocatable :: midpoint(:), triangles(:, :)
      real(dp), allocatable :: vertices(:, :)
      integer(ip) :: t, e, nv, nt
      logical :: changed

      allocate (halved(coarse%ne))
      halved = .false.
      do t = 1, coarse%nt
         if (marked(t)) halved(coarse%triangle_edges(:, t)) = .true.
      end do
      ! the closure: a halved edge halves its triangles' refinement edges (a chain that ends,
      ! each pass halving at least one more edge of a finite mesh)
      changed = .true.
      do while (changed)
         changed = .false.
         do t = 1, coarse%nt
            associate (edges => coarse%triangle_edges(:, t))
               if ((halved(edges(1)) .or. halved(edges(2))) .and. .not. halved(edges(3))) then
                  halved(edges(3)) = .true.
                  changed = .true.
               end if
            end associate
         end do
      end do
      ! midpoints numbered after the old vertices, in edge order
      allocate (midpoint(coarse%ne))
      midpoint = 0
      nv = coarse%nv
      do e = 1, coarse%ne
         if (.not. halved(e)) cycle
         nv = nv + 1
         midpoint(e) = nv
      end do
      allocate (vertices(2, nv), map%vertex_parents(2, nv))
      vertices(:, 1:coarse%nv) = coarse%vertices
      do t = 1, coarse%nv
         map%vertex_parents(:, t) = t
      end do
      do e = 1, coarse%ne
         if (midpoint(e) == 0) cycle
         associate (ends => coarse%edges(:, e))
            vertices(:, midpoint(e)) = 0.5_dp*(coarse%vertices(:, ends(1)) + coarse%vertices(:, ends(2)))
            map%vertex_parents(:, midpoint(e)) = ends
         end associate
      end do
      ! each triangle becomes 1 to 4 children
      allocate (triangles(3, coarse%nt + 3*count(halved)))
      nt = 0
      do t = 1, coarse%nt
         call children(coarse%triangles(:, t), midpoint(coarse%triangle_edges(:, t)), triangles, nt)
      end do
      call fine%init(vertices, triangles(:, 1:nt), 'bisection', err, diameter=coarse%diameter)
   end subroutine bisect_marked

   !> The children of triangle v = (v1, v2, v3), v3 newest, whose edges opposite its vertices
   !> have the midpoints m (0: not halved), appended to triangles(:, nt+1:).
   subroutine children(v, m, triangles, nt)
      integer(ip), intent(in) :: v(3), m(3)
      integer(ip), intent(inout) :: triangles(:, :)
      integer(ip), intent(inout) :: nt

      if (m(3) == 0) then
         nt = nt + 1
         triangles(:, nt) = v
         return
      end if
      ! (v3, v1, m3): its refinement edge (v3, v1) is the parent's edge opposite v2
      call half(v(3), v(1), m(3), m(2))
      ! (v2, v3, m3): its refinement edge (v2, v3) is the parent's edge opposite v1
      call half(v(2), v(3), m(3), m(1))

   contains

      !> The child (a, b, c) (c newest), bisected again when its refinement edge (a, b) has the
      !> midpoint mab.
      subroutine half(a, b, c, mab)
         integer(ip), intent(in) :: a, b, c, mab

         if (mab == 0) then
            nt = nt + 1
            triangles(:, nt) = [a, b, c]
         else
            nt = nt + 1
            triangles(:, nt) = [c, a, mab]
            nt = nt + 1
            triangles(:, nt) = [b, c, mab]
         end if
      end subroutine half
   end subroutine children
end module twomem_mesh_bisection
