!> Coarser meshes made from a mesh, for nested iteration on a mesh that was given without
!> coarser ones (a user's fine Gmsh mesh). Newton-min moves its contact front by about a layer
!> of vertices per step, so a fine mesh solved from a cold start takes a step per layer between
!> the first guess and the free boundary; a coarser mesh's solution, interpolated, starts it
!> within a layer or two, as nested iteration does on a refined hierarchy. Algebraic coarse
!> levels cannot play that part: their spaces approximate a smooth solution only to a fixed
!> fraction whatever h (smoothed aggregation's Galerkin solution misses a fixed share of the
!> deflection), so the contact set they predict is off by a number of layers that grows like
!> 1/h. A coarser *mesh* approximates to O(H²) like any P1 space.
!> The coarse mesh keeps a subset of the vertices (so every coarse vertex is a fine one: the
!> interpolation injects) and is made by half-edge collapses: a vertex v merges into a
!> neighbour u, the two triangles of the edge uv vanish and v's other triangles take u instead.
!> A collapse is taken when it keeps the mesh a conforming, positively oriented triangulation
!> (the link condition; no triangle turned over), keeps every triangle's shape above a quality
!> bound, and keeps the boundary's shape: a boundary vertex only moves along the boundary, into
!> a boundary neighbour, and only where the boundary is nearly straight (corners, such as a
!> re-entrant one, are kept). Each round visits the vertices in order and locks the neighbours
!> of a removed vertex, so that removals spread evenly; after each round, Lawson edge flips make
!> the triangulation Delaunay within its boundary again. Rounds go on until the mesh has the
!> asked fraction of the vertices or stops shrinking. Two threads share a round: the vertices are
!> split into two halves of their numbering (compact pieces of the domain for a mesh numbered
!> along it), and each half's collapses and flips are made by one thread where everything they
!> read or change lies in that half (a vertex's neighbours' neighbours, a flip's quadrilateral
!> and the triangles around it); the rest follows in order on one thread. The halves never share
!> a triangle or a vertex's data, so the result is the same on any number of threads, and
!> deterministic. Every fine vertex then reads a coarse P1 function through the coarse triangle
!> that contains it (a walk from the triangles of the vertex it was merged into), with its
!> barycentric weights; a fine vertex outside the coarse polygon (next to a curved boundary
!> that lost a vertex) takes those of the nearest triangle, clipped to it.
module twomem_mesh_coarsening
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_mesh_triangulation, only: mesh_t, signed_area, position_of
   implicit none
   private

   public :: vertex_interpolation_t, coarsen

   !> Fine vertex i reads Σ_k weight(k, i) u(vertex(k, i)) from a coarse P1 function u.
   type :: vertex_interpolation_t
      integer(ip), allocatable :: vertex(:, :)
      real(dp), allocatable :: weight(:, :)
   contains
      procedure :: apply => interpolation_apply
   end type vertex_interpolation_t

   !> the most triangles around a vertex while coarsening (a collapse that would exceed it is
   !> not taken)
   integer, parameter :: max_star = 24
   !> no triangle made by a collapse may have a shape quality below this (1 equilateral, 0 flat)
   real(dp), parameter :: min_quality = 0.15_dp
   !> a boundary vertex whose boundary turns by more than this (radians) is a corner, kept
   real(dp), parameter :: corner_turn = 0.35_dp
   !> a round that removes fewer than this fraction of the vertices ends the coarsening
   real(dp), parameter :: stall = 0.03_dp

   !> The mesh being coarsened: triangles (dead ones have vertex 0), the triangle across each
   !> of their edges (nbr(i, t): across the edge opposite t's local vertex i, 0 on the
   !> boundary; kept through collapses and flips, so that the Delaunay passes find a neighbour
   !> without searching stars), each vertex's triangles (star) and, for a boundary vertex, its
   !> two boundary neighbours.
   type :: work_mesh_t
      real(dp), allocatable :: x(:, :)
      integer(ip), allocatable :: tri(:, :), nbr(:, :), star(:, :), bnbr(:, :), merged_into(:)
      integer, allocatable :: nstar(:)
      logical, allocatable :: alive(:), boundary(:), corner(:)
      !> triangles changed since the last Delaunay pass looked at them
      logical, allocatable :: dirty(:)
      integer(ip) :: n_alive = 0
      !> the last vertex of the first half (the second: the others)
      integer(ip) :: split = 0
   end type work_mesh_t

contains

   !> u_fine = interpolation of the coarse P1 values u_coarse.
   subroutine interpolation_apply(self, u_coarse, u_fine)
      class(vertex_interpolation_t), intent(in) :: self
      real(dp), intent(in) :: u_coarse(:)
      real(dp), intent(out) :: u_fine(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(self, u_coarse, u_fine) private(i) schedule(static)
      do i = 1, size(u_fine, kind=ip)
         u_fine(i) = self%weight(1, i)*u_coarse(self%vertex(1, i)) + self%weight(2, i)*u_coarse(self%vertex(2, i)) + &
                     self%weight(3, i)*u_coarse(self%vertex(3, i))
      end do
      !$omp end parallel do
   end subroutine interpolation_apply

   !> A coarse mesh with about `fraction` of the vertices of `fine` (a whole mesh), and how the
   !> fine vertices interpolate from it. Fails (err) only if the coarse mesh is not a valid one,
   !> which the checks of every collapse are there to prevent.
   subroutine coarsen(fine, fraction, coarse, interpolation, err)
      type(mesh_t), intent(in) :: fine
      real(dp), intent(in) :: fraction
      type(mesh_t), intent(out) :: coarse
      type(vertex_interpolation_t), intent(out) :: interpolation
      type(error_t), allocatable, intent(out) :: err

      type(work_mesh_t) :: w
      integer(ip) :: before, goal
      integer(ip), allocatable :: number(:)

      call start(fine, w, err)
      if (allocated(err)) return
      goal = max(3_ip, int(fraction*real(fine%nv, dp), ip))
      do while (w%n_alive > goal)
         before = w%n_alive
         call collapse_round(w)
         call flip_to_delaunay(w)
         if (real(before - w%n_alive, dp) < stall*real(before, dp)) exit
      end do
      call compact(w, fine, coarse, number, err)
      if (allocated(err)) return
      call locate_vertices(w, fine, coarse, number, interpolation)
   end subroutine coarsen

   !> The work mesh of `fine`: stars, boundary neighbours and corners.
   subroutine start(fine, w, err)
      type(mesh_t), intent(in) :: fine
      type(work_mesh_t), intent(out) :: w
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: t, s, a, b, v, nb, e
      integer :: i, j, k
      integer(ip), allocatable :: count_b(:), first(:)

      w%x = fine%vertices
      w%tri = fine%triangles
      allocate (w%dirty(fine%nt))
      w%dirty = .false.
      allocate (w%star(max_star, fine%nv), w%nstar(fine%nv), w%bnbr(2, fine%nv), w%alive(fine%nv), &
                w%boundary(fine%nv), w%corner(fine%nv), w%merged_into(fine%nv), count_b(fine%nv))
      w%nstar = 0
      w%alive = .true.
      w%merged_into = 0
      w%n_alive = fine%nv
      w%split = fine%nv/2
      do t = 1, fine%nt
         do i = 1, 3
            v = w%tri(i, t)
            if (w%nstar(v) == max_star) then
               call make_error(err, exit_io, 'mesh coarsening', 'a vertex has too many triangles to coarsen the mesh')
               return
            end if
            w%nstar(v) = w%nstar(v) + 1
            w%star(w%nstar(v), v) = t
         end do
      end do
      ! the neighbours across edges, from the edge numbers: first(e) = 3(t − 1) + i for the
      ! first triangle t met with e opposite its vertex i
      allocate (w%nbr(3, fine%nt), first(fine%ne))
      w%nbr = 0
      first = 0
      do t = 1, fine%nt
         do i = 1, 3
            e = fine%triangle_edges(i, t)
            if (first(e) == 0) then
               first(e) = 3*(t - 1) + i
            else
               s = (first(e) - 1)/3 + 1
               j = int(first(e) - 3*(s - 1))
               w%nbr(i, t) = s
               w%nbr(j, s) = t
            end if
         end do
      end do
      deallocate (first)
      ! a boundary edge belongs to one triangle: it is (a, b) of triangle t, opposite its
      ! third vertex, with no triangle across
      w%boundary = .false.
      w%bnbr = 0
      count_b = 0
      do t = 1, fine%nt
         do i = 1, 3
            a = w%tri(i, t)
            b = w%tri(mod(i, 3) + 1, t)
            if (w%nbr(mod(i + 1, 3) + 1, t) /= 0) cycle
            w%boundary(a) = .true.
            w%boundary(b) = .true.
            count_b(a) = count_b(a) + 1
            count_b(b) = count_b(b) + 1
            ! (b is a's successor along the counter-clockwise boundary, a is b's predecessor)
            w%bnbr(2, a) = b
            w%bnbr(1, b) = a
         end do
      end do
      ! a corner: where the boundary turns, or is not a simple curve
      w%corner = .false.
      do v = 1, fine%nv
         if (.not. w%boundary(v)) cycle
         if (count_b(v) /= 2) then
            w%corner(v) = .true.
            cycle
         end if
         w%corner(v) = turn_at(w, v) > corner_turn
      end do
      ! a boundary component of three vertices cannot lose one
      do v = 1, fine%nv
         if (.not. w%boundary(v) .or. w%corner(v)) cycle
         nb = w%bnbr(1, v)
         do k = 1, 2
            nb = w%bnbr(1, nb)
         end do
         if (nb == v) w%corner(v) = .true.
      end do
   end subroutine start

   !> The angle (radians, 0 where straight) by which the boundary turns at boundary vertex v.
   pure real(dp) function turn_at(w, v) result(turn)
      type(work_mesh_t), intent(in) :: w
      integer(ip), intent(in) :: v

      real(dp) :: e1(2), e2(2)

      e1 = w%x(:, v) - w%x(:, w%bnbr(1, v))
      e2 = w%x(:, w%bnbr(2, v)) - w%x(:, v)
      turn = abs(atan2(e1(1)*e2(2) - e1(2)*e2(1), dot_product(e1, e2)))
   end function turn_at

   !> One pass of collapses over the vertices in order; a removed vertex's neighbours wait for
   !> the next round. Each half first takes its vertices whose neighbours' neighbours all lie in
   !> it (the halves side by side), then every vertex not yet visited in order (collapse_pass).
   subroutine collapse_round(w)
      type(work_mesh_t), intent(inout) :: w

      logical, allocatable :: locked(:), visited(:)
      integer(ip), allocatable :: mark(:)
      integer(ip) :: removed
      integer :: h

      allocate (locked(size(w%alive)), visited(size(w%alive)), mark(size(w%alive)))
      locked = .false.
      visited = .false.
      mark = 0
      removed = 0
      !$omp parallel do default(none) shared(w, locked, visited, mark) private(h) reduction(+:removed) &
      !$omp schedule(static, 1)
      do h = 1, 2
         call collapse_pass(w, h, locked, visited, mark, removed)
      end do
      !$omp end parallel do
      call collapse_pass(w, 0, locked, visited, mark, removed)
      w%n_alive = w%n_alive - removed
   end subroutine collapse_round

   !> The collapses of one pass, in order; removed counts them. h = 1, 2: half h's vertices whose
   !> neighbours' neighbours all lie in half h: all that best_target reads and collapse changes
   !> is then in half h (the stars of v and of its neighbours, the triangles across their edges,
   !> boundary neighbours), so the other half's thread never touches it. h = 0: every vertex
   !> that no such pass visited.
   subroutine collapse_pass(w, h, locked, visited, mark, removed)
      type(work_mesh_t), intent(inout) :: w
      integer, intent(in) :: h
      logical, intent(inout) :: locked(:), visited(:)
      integer(ip), intent(inout) :: mark(:), removed

      integer(ip) :: v, u, first, last
      integer :: k, i

      first = merge(w%split + 1, 1_ip, h == 2)
      last = merge(w%split, size(w%alive, kind=ip), h == 1)
      do v = first, last
         if (visited(v) .or. .not. w%alive(v) .or. w%corner(v) .or. locked(v)) cycle
         if (h > 0) then
            if (.not. two_rings_in_half(w, v, h)) cycle
            visited(v) = .true.
         end if
         u = best_target(w, v, mark)
         if (u == 0) cycle
         do k = 1, w%nstar(v)
            do i = 1, 3
               locked(w%tri(i, w%star(k, v))) = .true.
            end do
         end do
         call collapse(w, v, u)
         removed = removed + 1
      end do
   end subroutine collapse_pass

   !> Whether every vertex within two edges of v lies in half h. (It reads the stars of v and
   !> of its neighbours only once these are known to lie in half h: triangles of the other half
   !> may be changing meanwhile.)
   logical function two_rings_in_half(w, v, h) result(inside)
      type(work_mesh_t), intent(in) :: w
      integer(ip), intent(in) :: v
      integer, intent(in) :: h

      integer :: k, i, m, n
      integer(ip) :: a

      inside = .false.
      do k = 1, w%nstar(v)
         do i = 1, 3
            if (half(w, w%tri(i, w%star(k, v))) /= h) return
         end do
      end do
      do k = 1, w%nstar(v)
         do i = 1, 3
            a = w%tri(i, w%star(k, v))
            if (a == v) cycle
            do m = 1, w%nstar(a)
               do n = 1, 3
                  if (half(w, w%tri(n, w%star(m, a))) /= h) return
               end do
            end do
         end do
      end do
      inside = .true.
   end function two_rings_in_half

   !> The half (1 or 2) of vertex v.
   pure integer function half(w, v)
      type(work_mesh_t), intent(in) :: w
      integer(ip), intent(in) :: v

      half = merge(1, 2, v <= w%split)
   end function half

   !> The neighbour u into which v collapses best (the highest worst quality of the triangles
   !> that change), 0 if no collapse of v is allowed. mark(a) = v flags v's neighbours a.
   integer(ip) function best_target(w, v, mark) result(best)
      type(work_mesh_t), intent(in) :: w
      integer(ip), intent(in) :: v
      integer(ip), intent(inout) :: mark(:)

      integer(ip) :: u, link(3*max_star)
      integer :: k, i, n_link, m
      real(dp) :: q, best_q

      ! v's link: its neighbours, each once
      n_link = 0
      do k = 1, w%nstar(v)
         do i = 1, 3
            u = w%tri(i, w%star(k, v))
            if (u == v .or. mark(u) == v) cycle
            mark(u) = v
            n_link = n_link + 1
            link(n_link) = u
         end do
      end do
      best = 0
      ! (the boundary's turn at v as it is now: each collapse along a curve sharpens it)
      if (w%boundary(v)) then
         if (turn_at(w, v) > corner_turn) return
      end if
      best_q = min_quality
      do m = 1, n_link
         u = link(m)
         ! a boundary vertex moves along the boundary only
         if (w%boundary(v) .and. u /= w%bnbr(1, v) .and. u /= w%bnbr(2, v)) cycle
         q = collapse_quality(w, v, u, mark, best_q)
         if (q > best_q) then
            best_q = q
            best = u
         end if
      end do
   end function best_target

   !> The worst shape quality of v's triangles after v moves onto u, or −1 if the collapse is
   !> not allowed: too many triangles at u, the link condition broken (u and v must have in
   !> common exactly the neighbours opposite their edge: two inside, one on the boundary; more
   !> would make the mesh non-manifold), or a triangle turned over or flat. mark(a) = v flags
   !> v's neighbours a. A quality at most `floor` is returned without the link condition's
   !> check (the caller takes only a better one): that check reads u's star, the shapes only
   !> v's, whose triangles are at hand.
   real(dp) function collapse_quality(w, v, u, mark, floor) result(worst)
      type(work_mesh_t), intent(in) :: w
      integer(ip), intent(in) :: v, u
      integer(ip), intent(in) :: mark(:)
      real(dp), intent(in) :: floor

      integer(ip) :: t, p(3), a, seen(3*max_star)
      integer :: k, i, shared, common, n_seen
      real(dp) :: area

      worst = -1.0_dp
      ! the triangles of the edge uv: one where v is on the boundary (it moves along it, so uv
      ! is a boundary edge), else two
      shared = merge(1, 2, w%boundary(v))
      if (w%nstar(u) + w%nstar(v) - 2*shared > max_star) return
      worst = 1.0_dp
      do k = 1, w%nstar(v)
         t = w%star(k, v)
         if (any(w%tri(:, t) == u)) cycle
         p = w%tri(:, t)
         where (p == v) p = u
         area = signed_area(w%x(:, p(1)), w%x(:, p(2)), w%x(:, p(3)))
         if (area <= 0.0_dp) then
            worst = -1.0_dp
            return
         end if
         worst = min(worst, quality(w%x(:, p(1)), w%x(:, p(2)), w%x(:, p(3)), area))
      end do
      if (worst <= floor) return
      common = 0
      n_seen = 0
      do k = 1, w%nstar(u)
         do i = 1, 3
            a = w%tri(i, w%star(k, u))
            if (a == u .or. a == v .or. mark(a) /= v) cycle
            if (any(seen(1:n_seen) == a)) cycle
            n_seen = n_seen + 1
            seen(n_seen) = a
            common = common + 1
         end do
      end do
      if (common /= shared) worst = -1.0_dp
   end function collapse_quality

   !> 4√3 area / (sum of squared edges): 1 for an equilateral triangle, → 0 when it degenerates.
   pure real(dp) function quality(p1, p2, p3, area) result(q)
      real(dp), intent(in) :: p1(2), p2(2), p3(2), area

      q = 4.0_dp*sqrt(3.0_dp)*area/(sum((p2 - p1)**2) + sum((p3 - p2)**2) + sum((p1 - p3)**2))
   end function quality

   !> v merges into u: the triangles of the edge uv die, v's others take u (the caller counts
   !> the vertex removed).
   subroutine collapse(w, v, u)
      type(work_mesh_t), intent(inout) :: w
      integer(ip), intent(in) :: v, u

      integer(ip) :: t, a
      integer :: k, i

      do k = 1, w%nstar(v)
         t = w%star(k, v)
         if (any(w%tri(:, t) == u)) then
            ! the triangle (u, v, x) dies: the triangles across its edges vx and xu become
            ! neighbours across ux
            call relink(w, t, w%nbr(position_of(w%tri(:, t), u), t), w%nbr(position_of(w%tri(:, t), v), t))
            ! and it leaves its other vertices' stars
            do i = 1, 3
               a = w%tri(i, t)
               if (a /= v) call remove_from_star(w, a, t)
            end do
            w%tri(:, t) = 0
         else
            where (w%tri(:, t) == v) w%tri(:, t) = u
            w%nstar(u) = w%nstar(u) + 1
            w%star(w%nstar(u), u) = t
            w%dirty(t) = .true.
         end if
      end do
      if (w%boundary(v)) then
         ! u is v's boundary neighbour on one side: it takes v's neighbour on the other
         if (w%bnbr(1, v) == u) then
            w%bnbr(2, u) = w%bnbr(2, v)
            w%bnbr(1, w%bnbr(2, v)) = u
         else
            w%bnbr(1, u) = w%bnbr(1, v)
            w%bnbr(2, w%bnbr(1, v)) = u
         end if
      end if
      w%nstar(v) = 0
      w%alive(v) = .false.
      w%merged_into(v) = u
   end subroutine collapse

   !> Triangles p and q, the neighbours of a dying triangle t across two of its edges, become
   !> neighbours of each other across the edge that replaces both (either may be 0: boundary).
   subroutine relink(w, t, p, q)
      type(work_mesh_t), intent(inout) :: w
      integer(ip), intent(in) :: t, p, q

      if (p /= 0) call repoint(w, p, t, q)
      if (q /= 0) call repoint(w, q, t, p)
   end subroutine relink

   !> Triangle t's neighbour `old` becomes `new`.
   subroutine repoint(w, t, old, new)
      type(work_mesh_t), intent(inout) :: w
      integer(ip), intent(in) :: t, old, new

      integer :: i

      do i = 1, 3
         if (w%nbr(i, t) == old) then
            w%nbr(i, t) = new
            return
         end if
      end do
   end subroutine repoint

   subroutine remove_from_star(w, a, t)
      type(work_mesh_t), intent(inout) :: w
      integer(ip), intent(in) :: a, t

      integer :: k

      do k = 1, w%nstar(a)
         if (w%star(k, a) == t) then
            w%star(k, a) = w%star(w%nstar(a), a)
            w%nstar(a) = w%nstar(a) - 1
            return
         end if
      end do
   end subroutine remove_from_star

   !> Lawson flips in each half side by side on the triangles whose vertices all lie in it
   !> (owner(t) = h), then in order on every triangle (flip_passes).
   subroutine flip_to_delaunay(w)
      type(work_mesh_t), intent(inout) :: w

      integer, allocatable :: owner(:)
      integer(ip) :: t
      integer :: h

      allocate (owner(size(w%tri, 2)))
      !$omp parallel do default(none) shared(w, owner) private(t, h) schedule(static)
      do t = 1, size(w%tri, 2, kind=ip)
         owner(t) = 0
         if (w%tri(1, t) == 0) cycle
         h = half(w, w%tri(1, t))
         if (half(w, w%tri(2, t)) == h .and. half(w, w%tri(3, t)) == h) owner(t) = h
      end do
      !$omp end parallel do
      !$omp parallel do default(none) shared(w, owner) private(h) schedule(static, 1)
      do h = 1, 2
         call flip_passes(w, h, owner)
      end do
      !$omp end parallel do
      call flip_passes(w, 0, owner)
   end subroutine flip_to_delaunay

   !> Lawson flips until every interior edge is locally Delaunay. Only triangles that changed
   !> (a collapse, or a flip, marks them) are examined again; each flip raises the smallest angle
   !> of its quadrilateral, so the passes end. h = 1, 2: the triangles of half h only (a flip
   !> keeps them in it), and a flip only where the two triangles and the two across the edges
   !> that change sides are the half's; an edge it may not flip keeps its triangle marked for
   !> the pass with h = 0, which takes every triangle.
   subroutine flip_passes(w, h, owner)
      type(work_mesh_t), intent(inout) :: w
      integer, intent(in) :: h, owner(:)

      integer(ip) :: t, s, a, b, c, d
      integer :: i, pass
      logical :: any_flip

      do pass = 1, 50
         any_flip = .false.
         do t = 1, size(w%tri, 2, kind=ip)
            if (.not. mine(t)) cycle
            if (.not. w%dirty(t)) cycle
            w%dirty(t) = .false.
            if (w%tri(1, t) == 0) cycle
            do i = 1, 3
               s = w%nbr(mod(i + 1, 3) + 1, t)
               if (s == 0) cycle
               if (.not. mine(s)) then
                  w%dirty(t) = .true.
                  cycle
               end if
               a = w%tri(i, t)
               b = w%tri(mod(i, 3) + 1, t)
               c = w%tri(mod(i + 1, 3) + 1, t)
               d = sum(w%tri(:, s)) - a - b
               if (.not. should_flip(w, a, b, c, d)) cycle
               if (w%nstar(c) == max_star .or. w%nstar(d) == max_star) cycle
               ! (the triangles across bc and ad get a new neighbour: flip)
               if (.not. mine(w%nbr(position_of(w%tri(:, t), a), t)) .or. &
                   .not. mine(w%nbr(position_of(w%tri(:, s), b), s))) then
                  w%dirty(t) = .true.
                  cycle
               end if
               call flip(w, t, s, a, b, c, d)
               w%dirty(t) = .true.
               w%dirty(s) = .true.
               any_flip = .true.
               exit
            end do
         end do
         if (.not. any_flip) exit
      end do
   contains
      !> whether this pass may change triangle r (0: none, across the boundary)
      logical function mine(r)
         integer(ip), intent(in) :: r

         mine = h == 0 .or. r == 0
         if (.not. mine) mine = owner(r) == h
      end function mine
   end subroutine flip_passes

   !> Triangles (a, b, c) and (b, a, d), both counter-clockwise: whether d lies inside the
   !> circumcircle of (a, b, c) and the quadrilateral is convex (the flip to c–d is valid).
   logical function should_flip(w, a, b, c, d)
      type(work_mesh_t), intent(in) :: w
      integer(ip), intent(in) :: a, b, c, d

      real(dp) :: pa(2), pb(2), pc(2), m(3, 3), det, scale

      should_flip = .false.
      if (signed_area(w%x(:, a), w%x(:, d), w%x(:, c)) <= 0.0_dp) return
      if (signed_area(w%x(:, d), w%x(:, b), w%x(:, c)) <= 0.0_dp) return
      pa = w%x(:, a) - w%x(:, d)
      pb = w%x(:, b) - w%x(:, d)
      pc = w%x(:, c) - w%x(:, d)
      m(1, :) = [pa(1), pa(2), sum(pa**2)]
      m(2, :) = [pb(1), pb(2), sum(pb**2)]
      m(3, :) = [pc(1), pc(2), sum(pc**2)]
      det = m(1, 1)*(m(2, 2)*m(3, 3) - m(2, 3)*m(3, 2)) - m(1, 2)*(m(2, 1)*m(3, 3) - m(2, 3)*m(3, 1)) + &
            m(1, 3)*(m(2, 1)*m(3, 2) - m(2, 2)*m(3, 1))
      scale = sum(pa**2) + sum(pb**2) + sum(pc**2)
      ! (a margin against round-off, so that co-circular quadrilaterals do not flip back)
      should_flip = det > 1.0e-10_dp*scale**2
   end function should_flip

   !> (a, b, c) = t and (b, a, d) = s become (a, d, c) and (d, b, c).
   subroutine flip(w, t, s, a, b, c, d)
      type(work_mesh_t), intent(inout) :: w
      integer(ip), intent(in) :: t, s, a, b, c, d

      integer(ip) :: across_bc, across_ca, across_ad, across_db

      across_bc = w%nbr(position_of(w%tri(:, t), a), t)
      across_ca = w%nbr(position_of(w%tri(:, t), b), t)
      across_ad = w%nbr(position_of(w%tri(:, s), b), s)
      across_db = w%nbr(position_of(w%tri(:, s), a), s)
      w%tri(:, t) = [a, d, c]
      w%tri(:, s) = [d, b, c]
      w%nbr(:, t) = [s, across_ca, across_ad]
      w%nbr(:, s) = [across_bc, t, across_db]
      if (across_ad /= 0) call repoint(w, across_ad, s, t)
      if (across_bc /= 0) call repoint(w, across_bc, t, s)
      call remove_from_star(w, a, s)
      call remove_from_star(w, b, t)
      w%nstar(c) = w%nstar(c) + 1
      w%star(w%nstar(c), c) = s
      w%nstar(d) = w%nstar(d) + 1
      w%star(w%nstar(d), d) = t
   end subroutine flip

   !> The coarse mesh: the live vertices (in their order) and triangles. number(v) is the coarse
   !> number of live fine vertex v.
   subroutine compact(w, fine, coarse, number, err)
      type(work_mesh_t), intent(in) :: w
      type(mesh_t), intent(in) :: fine
      type(mesh_t), intent(out) :: coarse
      integer(ip), allocatable, intent(out) :: number(:)
      type(error_t), allocatable, intent(out) :: err

      integer(ip), allocatable :: triangles(:, :)
      integer(ip) :: v, t, nv, nt

      allocate (number(size(w%alive)))
      number = 0
      nv = 0
      do v = 1, size(w%alive, kind=ip)
         if (.not. w%alive(v)) cycle
         nv = nv + 1
         number(v) = nv
      end do
      nt = count(w%tri(1, :) /= 0, kind=ip)
      allocate (triangles(3, nt))
      nt = 0
      do t = 1, size(w%tri, 2, kind=ip)
         if (w%tri(1, t) == 0) cycle
         nt = nt + 1
         triangles(:, nt) = number(w%tri(:, t))
      end do
      call coarse%init(w%x(:, pack([(v, v=1, size(w%alive, kind=ip))], w%alive)), triangles, 'mesh coarsening', err, &
                       diameter=fine%diameter)
   end subroutine compact

   !> Every fine vertex's coarse triangle and barycentric weights: a live vertex reads its own
   !> value; a removed one is found by a walk from a triangle of the vertex it was merged into
   !> (following merges to a live one), towards the point across the edge where it lies outside.
   subroutine locate_vertices(w, fine, coarse, number, interpolation)
      type(work_mesh_t), intent(in) :: w
      type(mesh_t), intent(in) :: fine
      type(mesh_t), intent(in) :: coarse
      integer(ip), intent(in) :: number(:)
      type(vertex_interpolation_t), intent(out) :: interpolation

      integer(ip) :: v, u

      allocate (interpolation%vertex(3, fine%nv), interpolation%weight(3, fine%nv))
      !$omp parallel do default(none) shared(w, fine, coarse, number, interpolation) private(v, u) schedule(dynamic, 256)
      do v = 1, fine%nv
         if (w%alive(v)) then
            interpolation%vertex(:, v) = number(v)
            interpolation%weight(:, v) = [1.0_dp, 0.0_dp, 0.0_dp]
            cycle
         end if
         u = v
         do while (.not. w%alive(u))
            u = w%merged_into(u)
         end do
         call walk(coarse, coarse%patch_triangles(coarse%patch_ptr(number(u))), fine%vertices(:, v), &
                   interpolation%vertex(:, v), interpolation%weight(:, v))
      end do
      !$omp end parallel do
   end subroutine locate_vertices

   !> From triangle t, walk towards point x: the containing triangle's vertices and x's
   !> barycentric weights there, or the last triangle's, clipped, where the walk leaves the
   !> mesh (x outside the coarse polygon) or does not settle.
   subroutine walk(mesh, t0, x, vertex, weight)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t0
      real(dp), intent(in) :: x(2)
      integer(ip), intent(out) :: vertex(3)
      real(dp), intent(out) :: weight(3)

      integer(ip) :: t, e, next
      integer :: step, i
      real(dp) :: b(3)

      t = t0
      do step = 1, 10000
         b = barycentric(mesh, t, x)
         i = minloc(b, dim=1)
         if (b(i) >= -1.0e-12_dp) exit
         e = mesh%triangle_edges(i, t)
         next = mesh%edge_triangles(1, e)
         if (next == t) next = mesh%edge_triangles(2, e)
         if (next == 0) exit
         t = next
      end do
      vertex = mesh%triangles(:, t)
      b = max(b, 0.0_dp)
      weight = b/sum(b)
   end subroutine walk

   !> The barycentric coordinates of x in triangle t (coordinate i belongs to local vertex i,
   !> whose opposite edge is triangle_edges(i, t)).
   pure function barycentric(mesh, t, x) result(b)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: x(2)
      real(dp) :: b(3)

      associate (p => mesh%vertices(:, mesh%triangles(:, t)))
         b(1) = signed_area(x, p(:, 2), p(:, 3))
         b(2) = signed_area(p(:, 1), x, p(:, 3))
         b(3) = signed_area(p(:, 1), p(:, 2), x)
      end associate
      b = b/sum(b)
   end function barycentric
end module twomem_mesh_coarsening
