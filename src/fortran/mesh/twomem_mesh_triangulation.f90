!> A conforming triangulation with everything the solver asks of it: counter-clockwise triangles,
!> edges with their one or two neighbours, the boundary (edges that belong to one triangle), vertex
!> patches, element sizes and the domain diameter. `init` is the single gate every mesh passes
!> through, whoever made it (generator, Gmsh reader, refinement): it orients, validates and
!> derives, and rejects what would later break the discretization (zero areas, non-manifold
!> edges, unused or out-of-range vertices) with an error rather than a crash.
module twomem_mesh_triangulation
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   implicit none
   private

   public :: mesh_t, signed_area, corner_of, position_of

   type :: mesh_t
      integer(ip) :: nv = 0, nt = 0, ne = 0
      !> vertex coordinates, (2, nv)
      real(dp), allocatable :: vertices(:, :)
      !> triangle vertices, (3, nt), counter-clockwise
      integer(ip), allocatable :: triangles(:, :)
      !> edge end points, (2, ne), first < second (not kept once a run's hierarchy is built: see
      !> drop_refinement_tables)
      integer(ip), allocatable :: edges(:, :)
      !> edge of triangle t opposite its local vertex i, (3, nt)
      integer(ip), allocatable :: triangle_edges(:, :)
      !> triangles on either side of an edge, (2, ne); the second is 0 on the boundary (not kept
      !> once a run's hierarchy is built: see drop_refinement_tables)
      integer(ip), allocatable :: edge_triangles(:, :)
      logical, allocatable :: boundary_vertex(:), boundary_edge(:)
      !> vertex patches in CSR form: the triangles around vertex a are
      !> patch_triangles(patch_ptr(a):patch_ptr(a+1)-1)
      integer(ip), allocatable :: patch_ptr(:), patch_triangles(:)
      !> triangle areas (their diameters are not stored: `diameter_of`)
      real(dp), allocatable :: area(:)
      !> diameter of the domain (largest distance between boundary vertices)
      real(dp) :: diameter = 0.0_dp
      !> triangles whose orientation `init` reversed
      integer(ip) :: n_flipped = 0
      !> Distributed runs: this rank's piece of a partitioned mesh. Triangles 1..nt_owned are
      !> its own; the rest are the ghost layer (the other ranks' triangles that share a vertex
      !> with its own), which the estimators' patches need. Every local vertex, edge and
      !> triangle carries its number in the whole (serial) mesh, so results are gathered in the
      !> serial layout. vertex_owner is the lowest rank owning a triangle at the vertex (−1 for
      !> a vertex of ghost triangles only). A whole mesh is one rank's piece of itself:
      !> nt_owned = nt, global numbers = local ones, every owner 0; it stores none of these
      !> arrays (37 bytes per vertex), which `whole` tells: read them through global_vertex_of,
      !> global_triangle_of, vertex_owner_of and triangle_owner_of.
      integer(ip) :: nt_owned = 0
      integer(ip) :: nv_global = 0, nt_global = 0, ne_global = 0
      integer(ip), allocatable :: global_vertex(:), global_triangle(:), global_edge(:)
      integer, allocatable :: triangle_owner(:), vertex_owner(:)
   contains
      procedure :: init => mesh_init
      procedure :: free => mesh_free
      procedure :: n_boundary_vertices
      procedure :: total_area
      procedure :: diameter_of
      procedure :: set_whole
      procedure :: whole => is_whole
      procedure :: global_vertex_of, global_triangle_of, vertex_owner_of, triangle_owner_of
      procedure :: in_subdomain
      procedure :: vertices_by_first_triangle
      procedure :: drop_refinement_tables
   end type mesh_t

contains

   !> The local index (1..3) of vertex a in triangle t, 0 if a is not one of its corners.
   !> (A loop, not findloc with DIM: that allocates its result, millions of times in assembly.)
   pure integer function corner_of(mesh, t, a) result(i)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t, a

      do i = 1, 3
         if (mesh%triangles(i, t) == a) return
      end do
      i = 0
   end function corner_of

   !> The position of `value` in `list`, 0 if absent (for the short lists of patches and rows).
   pure integer function position_of(list, value) result(i)
      integer(ip), intent(in) :: list(:), value

      do i = 1, size(list)
         if (list(i) == value) return
      end do
      i = 0
   end function position_of

   !> The diameter of triangle t, its longest edge (a few operations: cheaper to compute where
   !> needed than 16 bytes per vertex to store). The same bits whatever the orientation.
   elemental real(dp) function diameter_of(self, t) result(h)
      class(mesh_t), intent(in) :: self
      integer(ip), intent(in) :: t

      associate (v => self%triangles(:, t))
         h = max(norm2(self%vertices(:, v(2)) - self%vertices(:, v(1))), &
                 norm2(self%vertices(:, v(3)) - self%vertices(:, v(2))), &
                 norm2(self%vertices(:, v(1)) - self%vertices(:, v(3))))
      end associate
   end function diameter_of

   pure function signed_area(p1, p2, p3) result(a)
      real(dp), intent(in) :: p1(2), p2(2), p3(2)
      real(dp) :: a

      a = 0.5_dp*((p2(1) - p1(1))*(p3(2) - p1(2)) - (p3(1) - p1(1))*(p2(2) - p1(2)))
   end function signed_area

   !> Build a mesh from coordinates and connectivity. `source` names the origin in messages
   !> (a file name, 'disk generator', ...). A caller that knows the domain's diameter (the
   !> refinement of a mesh covers the same domain) passes it to skip the O(n_b²) search.
   !> vertex_names(a) and triangle_names(t) are the numbers messages give them, where the caller
   !> renumbered a file's mesh (absent or empty: a and t).
   subroutine mesh_init(self, vertices, triangles, source, err, diameter, vertex_names, triangle_names)
      class(mesh_t), intent(inout) :: self
      real(dp), intent(in) :: vertices(:, :)
      integer(ip), intent(in) :: triangles(:, :)
      character(len=*), intent(in) :: source
      type(error_t), allocatable, intent(out) :: err
      real(dp), intent(in), optional :: diameter
      integer(ip), intent(in), optional :: vertex_names(:), triangle_names(:)

      integer(ip) :: t, i, swap
      real(dp) :: a, h2
      character(len=160) :: msg

      call self%free()
      if (size(vertices, 1) /= 2 .or. size(triangles, 1) /= 3) then
         call make_error(err, exit_bad_input, source, 'mesh arrays have the wrong shape')
         return
      end if
      self%nv = int(size(vertices, 2), ip)
      self%nt = int(size(triangles, 2), ip)
      if (self%nt == 0) then
         call make_error(err, exit_bad_input, source, 'the mesh has no triangles')
         return
      end if
      ! 1e150 keeps squared distances finite; ieee_is_finite does not trap on NaN
      if (.not. all(ieee_is_finite(vertices))) then
         call make_error(err, exit_bad_input, source, 'vertex coordinates are not finite')
         return
      end if
      if (any(abs(vertices) > 1.0e150_dp)) then
         call make_error(err, exit_bad_input, source, 'vertex coordinates exceed 1e150')
         return
      end if
      if (any(triangles < 1) .or. any(triangles > self%nv)) then
         call make_error(err, exit_bad_input, source, 'a triangle refers to a vertex that does not exist')
         return
      end if
      self%vertices = vertices
      self%triangles = triangles
      allocate (self%area(self%nt))
      self%n_flipped = 0
      do t = 1, self%nt
         associate (v => self%triangles(:, t))
            if (v(1) == v(2) .or. v(2) == v(3) .or. v(1) == v(3)) then
               write (msg, '(a,i0,a)') 'triangle ', named(t, triangle_names), ' repeats a vertex'
               call make_error(err, exit_bad_input, source, msg)
               return
            end if
            ! the squared diameter without norm2's scaling: coordinates below 1e150 keep it finite
            h2 = max(sum((self%vertices(:, v(2)) - self%vertices(:, v(1)))**2), &
                     sum((self%vertices(:, v(3)) - self%vertices(:, v(2)))**2), &
                     sum((self%vertices(:, v(1)) - self%vertices(:, v(3)))**2))
            a = signed_area(self%vertices(:, v(1)), self%vertices(:, v(2)), self%vertices(:, v(3)))
            ! A sliver this thin has no usable gradient: its stiffness would be round-off.
            if (abs(a) <= 1.0e3_dp*epsilon(1.0_dp)*h2) then
               write (msg, '(a,i0,a)') 'triangle ', named(t, triangle_names), ' has zero area (degenerate)'
               call make_error(err, exit_bad_input, source, msg)
               return
            end if
            if (a < 0.0_dp) then
               swap = v(2)
               self%triangles(2, t) = v(3)
               self%triangles(3, t) = swap
               self%n_flipped = self%n_flipped + 1
            end if
            self%area(t) = abs(a)
         end associate
      end do

      call build_patches(self)
      do i = 1, self%nv
         if (self%patch_ptr(i + 1) == self%patch_ptr(i)) then
            write (msg, '(a,i0,a)') 'vertex ', named(i, vertex_names), ' belongs to no triangle (unused node)'
            call make_error(err, exit_bad_input, source, msg)
            return
         end if
      end do
      call build_edges(self, source, err, vertex_names, triangle_names)
      if (allocated(err)) return
      if (present(diameter)) then
         self%diameter = diameter
      else
         self%diameter = boundary_diameter(self)
      end if
      call self%set_whole()
   end subroutine mesh_init

   !> Mark the mesh as a whole: one rank's piece of itself.
   subroutine set_whole(self)
      class(mesh_t), intent(inout) :: self

      self%nt_owned = self%nt
      self%nv_global = self%nv
      self%nt_global = self%nt
      self%ne_global = self%ne
      if (allocated(self%global_vertex)) deallocate (self%global_vertex)
      if (allocated(self%global_triangle)) deallocate (self%global_triangle)
      if (allocated(self%global_edge)) deallocate (self%global_edge)
      if (allocated(self%triangle_owner)) deallocate (self%triangle_owner)
      if (allocated(self%vertex_owner)) deallocate (self%vertex_owner)
   end subroutine set_whole

   !> Whether the mesh is whole (see the type): no numbering of a piece stored.
   pure logical function is_whole(self)
      class(mesh_t), intent(in) :: self

      is_whole = .not. allocated(self%global_vertex)
   end function is_whole

   !> Number of local vertex a in the whole mesh.
   elemental integer(ip) function global_vertex_of(self, a) result(g)
      class(mesh_t), intent(in) :: self
      integer(ip), intent(in) :: a

      if (allocated(self%global_vertex)) then
         g = self%global_vertex(a)
      else
         g = a
      end if
   end function global_vertex_of

   !> Number of local triangle t in the whole mesh.
   elemental integer(ip) function global_triangle_of(self, t) result(g)
      class(mesh_t), intent(in) :: self
      integer(ip), intent(in) :: t

      if (allocated(self%global_triangle)) then
         g = self%global_triangle(t)
      else
         g = t
      end if
   end function global_triangle_of

   !> The rank owning local vertex a (see the type).
   elemental integer function vertex_owner_of(self, a) result(rank)
      class(mesh_t), intent(in) :: self
      integer(ip), intent(in) :: a

      if (allocated(self%vertex_owner)) then
         rank = self%vertex_owner(a)
      else
         rank = 0
      end if
   end function vertex_owner_of

   !> The rank owning local triangle t.
   elemental integer function triangle_owner_of(self, t) result(rank)
      class(mesh_t), intent(in) :: self
      integer(ip), intent(in) :: t

      if (allocated(self%triangle_owner)) then
         rank = self%triangle_owner(t)
      else
         rank = 0
      end if
   end function triangle_owner_of

   !> Vertices of this rank's own triangles (the solver's unknowns live there; the other local
   !> vertices belong to the ghost layer only).
   function in_subdomain(self) result(inside)
      class(mesh_t), intent(in) :: self
      logical, allocatable :: inside(:)

      integer(ip) :: a, m

      allocate (inside(self%nv))
      do a = 1, self%nv
         inside(a) = .false.
         do m = self%patch_ptr(a), self%patch_ptr(a + 1) - 1
            if (self%patch_triangles(m) <= self%nt_owned) then
               inside(a) = .true.
               exit
            end if
         end do
      end do
   end function in_subdomain

   !> Every vertex once, in the order of its first patch triangle (patches list their triangles
   !> in ascending order). Red refinement numbers triangles along its tree, so loops over
   !> vertices' patches in this order find their triangles' data in cache: in vertex order,
   !> building the stiffness rows and the patch signatures waited on memory.
   function vertices_by_first_triangle(self) result(order)
      class(mesh_t), intent(in) :: self
      integer(ip), allocatable :: order(:)

      integer(ip) :: t, a, n
      integer :: i

      allocate (order(self%nv))
      n = 0
      do t = 1, self%nt
         do i = 1, 3
            a = self%triangles(i, t)
            if (self%patch_triangles(self%patch_ptr(a)) /= t) cycle
            n = n + 1
            order(n) = a
         end do
      end do
   end function vertices_by_first_triangle

   subroutine mesh_free(self)
      class(mesh_t), intent(inout) :: self

      self%nv = 0
      self%nt = 0
      self%ne = 0
      self%diameter = 0.0_dp
      self%n_flipped = 0
      self%nt_owned = 0
      self%nv_global = 0
      self%nt_global = 0
      self%ne_global = 0
      if (allocated(self%global_vertex)) deallocate (self%global_vertex)
      if (allocated(self%global_triangle)) deallocate (self%global_triangle)
      if (allocated(self%global_edge)) deallocate (self%global_edge)
      if (allocated(self%triangle_owner)) deallocate (self%triangle_owner)
      if (allocated(self%vertex_owner)) deallocate (self%vertex_owner)
      if (allocated(self%vertices)) deallocate (self%vertices)
      if (allocated(self%triangles)) deallocate (self%triangles)
      if (allocated(self%edges)) deallocate (self%edges)
      if (allocated(self%triangle_edges)) deallocate (self%triangle_edges)
      if (allocated(self%edge_triangles)) deallocate (self%edge_triangles)
      if (allocated(self%boundary_vertex)) deallocate (self%boundary_vertex)
      if (allocated(self%boundary_edge)) deallocate (self%boundary_edge)
      if (allocated(self%patch_ptr)) deallocate (self%patch_ptr)
      if (allocated(self%patch_triangles)) deallocate (self%patch_triangles)
      if (allocated(self%area)) deallocate (self%area)
   end subroutine mesh_free

   pure integer(ip) function n_boundary_vertices(self)
      class(mesh_t), intent(in) :: self

      n_boundary_vertices = int(count(self%boundary_vertex), ip)
   end function n_boundary_vertices

   pure real(dp) function total_area(self)
      class(mesh_t), intent(in) :: self

      total_area = sum(self%area)
   end function total_area

   subroutine build_patches(self)
      type(mesh_t), intent(inout) :: self

      integer(ip) :: t, i, a
      integer(ip), allocatable :: fill(:)

      allocate (self%patch_ptr(self%nv + 1))
      self%patch_ptr = 0
      do t = 1, self%nt
         do i = 1, 3
            a = self%triangles(i, t)
            self%patch_ptr(a + 1) = self%patch_ptr(a + 1) + 1
         end do
      end do
      self%patch_ptr(1) = 1
      do a = 1, self%nv
         self%patch_ptr(a + 1) = self%patch_ptr(a + 1) + self%patch_ptr(a)
      end do
      allocate (self%patch_triangles(self%patch_ptr(self%nv + 1) - 1))
      allocate (fill(self%nv))
      fill = self%patch_ptr(1:self%nv)
      do t = 1, self%nt
         do i = 1, 3
            a = self%triangles(i, t)
            self%patch_triangles(fill(a)) = t
            fill(a) = fill(a) + 1
         end do
      end do
   end subroutine build_patches

   !> Edges are found vertex by vertex: each edge is owned by its smaller end point, so it is
   !> discovered from that vertex's patch only, without a global sort.
   subroutine build_edges(self, source, err, vertex_names, triangle_names)
      type(mesh_t), intent(inout) :: self
      character(len=*), intent(in) :: source
      type(error_t), allocatable, intent(out) :: err
      integer(ip), intent(in), optional :: vertex_names(:), triangle_names(:)

      integer(ip) :: a, k, t, i, j, b, e, n_local, max_edges
      integer(ip), allocatable :: local_b(:), local_e(:)
      integer(ip), allocatable :: edges(:, :), edge_tris(:, :)
      character(len=160) :: msg

      max_edges = 3*self%nt
      allocate (edges(2, max_edges), edge_tris(2, max_edges))
      edge_tris = 0
      allocate (self%triangle_edges(3, self%nt))
      allocate (local_b(2*maxval(self%patch_ptr(2:) - self%patch_ptr(:self%nv)) + 2))
      allocate (local_e(size(local_b)))
      self%ne = 0
      do a = 1, self%nv
         n_local = 0
         do k = self%patch_ptr(a), self%patch_ptr(a + 1) - 1
            t = self%patch_triangles(k)
            do i = 1, 3
               b = self%triangles(i, t)
               if (b <= a) cycle
               e = 0
               do j = 1, n_local
                  if (local_b(j) == b) then
                     e = local_e(j)
                     exit
                  end if
               end do
               if (e == 0) then
                  self%ne = self%ne + 1
                  e = self%ne
                  edges(:, e) = [a, b]
                  edge_tris(1, e) = t
                  n_local = n_local + 1
                  local_b(n_local) = b
                  local_e(n_local) = e
               else if (edge_tris(2, e) == 0) then
                  edge_tris(2, e) = t
               else
                  write (msg, '(a,i0,a,i0,a)') 'edge between vertices ', named(a, vertex_names), ' and ', &
                     named(b, vertex_names), &
                     ' belongs to more than two triangles (non-manifold or duplicate triangles)'
                  call make_error(err, exit_bad_input, source, msg)
                  return
               end if
               ! the edge (a, b) is opposite the third vertex of t
               do j = 1, 3
                  if (self%triangles(j, t) /= a .and. self%triangles(j, t) /= b) then
                     self%triangle_edges(j, t) = e
                  end if
               end do
            end do
         end do
      end do
      self%edges = edges(:, 1:self%ne)
      self%edge_triangles = edge_tris(:, 1:self%ne)
      allocate (self%boundary_edge(self%ne), self%boundary_vertex(self%nv))
      self%boundary_edge = self%edge_triangles(2, :) == 0
      self%boundary_vertex = .false.
      do e = 1, self%ne
         if (self%boundary_edge(e)) self%boundary_vertex(self%edges(:, e)) = .true.
      end do
      ! Two triangles sharing an edge must lie on opposite sides of it once both are
      ! counter-clockwise; the same side means they overlap (a folded mesh).
      do e = 1, self%ne
         if (self%boundary_edge(e)) cycle
         if (same_side(self, e)) then
            write (msg, '(a,i0,a,i0,a)') 'triangles ', named(self%edge_triangles(1, e), triangle_names), ' and ', &
               named(self%edge_triangles(2, e), triangle_names), ' overlap (folded mesh)'
            call make_error(err, exit_bad_input, source, msg)
            return
         end if
      end do
   end subroutine build_edges

   !> The number by which messages name entity k: names(k), or k itself without names (absent
   !> or empty).
   pure integer(ip) function named(k, names)
      integer(ip), intent(in) :: k
      integer(ip), intent(in), optional :: names(:)

      named = k
      if (present(names)) then
         if (size(names) > 0) named = names(k)
      end if
   end function named

   logical function same_side(self, e)
      type(mesh_t), intent(in) :: self
      integer(ip), intent(in) :: e

      integer(ip) :: k, t, i, apex(2)
      real(dp) :: s(2)

      do k = 1, 2
         t = self%edge_triangles(k, e)
         do i = 1, 3
            if (self%triangle_edges(i, t) == e) apex(k) = self%triangles(i, t)
         end do
         s(k) = signed_area(self%vertices(:, self%edges(1, e)), self%vertices(:, self%edges(2, e)), &
                            self%vertices(:, apex(k)))
      end do
      ! signs, not the product: two areas near the 1e150 coordinate limit multiply to overflow
      same_side = (s(1) > 0.0_dp .and. s(2) > 0.0_dp) .or. (s(1) < 0.0_dp .and. s(2) < 0.0_dp)
   end function same_side

   real(dp) function boundary_diameter(self) result(d)
      type(mesh_t), intent(in) :: self

      integer(ip), allocatable :: b(:)
      integer(ip) :: i, j

      b = pack([(i, i=1, self%nv)], self%boundary_vertex)
      d = 0.0_dp
      do i = 1, size(b)
         do j = i + 1, size(b)
            d = max(d, norm2(self%vertices(:, b(i)) - self%vertices(:, b(j))))
         end do
      end do
   end function boundary_diameter

   !> Free what only building, refining or partitioning this mesh reads: the edges' end points,
   !> the triangles on either side of each edge and the global edge numbers. Once a run's
   !> hierarchy is built no level is refined or partitioned again, and these are 61 MB of the
   !> finest mesh at 10⁶ vertices (77 MB over all levels).
   subroutine drop_refinement_tables(self)
      class(mesh_t), intent(inout) :: self

      if (allocated(self%edges)) deallocate (self%edges)
      if (allocated(self%edge_triangles)) deallocate (self%edge_triangles)
      if (allocated(self%global_edge)) deallocate (self%global_edge)
   end subroutine drop_refinement_tables
end module twomem_mesh_triangulation
