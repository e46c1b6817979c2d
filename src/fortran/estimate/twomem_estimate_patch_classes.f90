!> Patch classes: in a red-refined hierarchy the patch of a vertex inside a coarse triangle is,
!> on every level, a scaled and translated copy of one patch per coarse triangle, and likewise
!> for the vertices on a coarse edge and at a coarse vertex. The condensed multiplier matrix H of
!> a patch problem (twomem_estimate_patch) depends only on its triangles' shape classes, their
!> edges and the relative orientation of their traces, not on the ratio to the class size nor on
!> the data, so it is factorized once per distinct patch (a signature) for the whole hierarchy
!> and both membranes, and each evaluation only assembles right-hand sides and applies the
!> factor. A signature lists, with the patch triangles in a canonical order (by class and local
!> index of the patch vertex, so that it does not depend on the mesh numbering), their classes,
!> zero-flux edges, inner-edge numbering and relative trace signs: exactly what H is made of, so
!> patches of one signature share H by construction, whatever the geometry. Two tables: `single`
!> for the patches of a mesh's own triangles (discretization flux, single-mesh algebraic flux),
!> `refined` for the patches of a coarse vertex on the red refinement of its triangles
!> (multilevel algebraic flux), whose multipliers inside each coarse triangle come first as a
!> block (twomem_estimate_patch). The patches of vertices on ∂Ω have signatures too: their edges
!> on ∂Ω are free (no multiplier, nothing pinned). Boundary patches are O(√N) of all, but each
!> takes several times an interior one's time on the general path, which weighs on small
!> meshes. Only patches too large for the fixed-size factors keep the general path.
module twomem_estimate_patch_classes
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_patch, only: link_edge, on_opposite_edge, edge_neumann
   use twomem_estimate_patch_factor, only: patch_factor_t, condensed_factor, max_theta
   implicit none
   private

   public :: patch_table_t, patch_signature_t, patch_order, stored_order, edge_signs, max_patch, no_code

   !> the most triangles of a factorized patch (larger ones take the general path), so that the
   !> per-patch work arrays have fixed sizes
   integer, parameter :: max_patch = 64

   !> patches of at most this many triangles keep their canonical order (level_ids_t%order),
   !> 3 bits per position in one integer
   integer, parameter :: max_coded = 8, no_code = -1

   !> One distinct patch: per patch triangle (canonical order, children of a coarse triangle
   !> consecutively for `refined`) its class, its zero-flux edge (0: none) and its edge links
   !> (twomem_estimate_patch), and the factor of H.
   type :: patch_signature_t
      integer, allocatable :: classes(:), neumann(:), links(:, :)
      !> per coarse triangle (per triangle for `single`): the local index of the patch vertex
      integer, allocatable :: corners(:)
      type(patch_factor_t) :: factor
      !> the key while the table is built
      integer, allocatable :: key(:)
   end type patch_signature_t

   type :: level_ids_t
      !> per vertex of the patch mesh: its signature, 0 for a patch on the general path (too
      !> large for the fixed-size factors, or outside this rank's subdomain)
      integer, allocatable :: id(:)
      !> per vertex with a signature: the canonical order of its patch triangles (patch_order)
      !> as their positions in the patch list, coded 3 bits each (stored_order); no_code for
      !> a patch of more than max_coded triangles. Every evaluation visits every patch, so the
      !> order is found once here instead of by a sort in every evaluation.
      integer, allocatable :: order(:)
   end type level_ids_t

   type :: patch_table_t
      integer :: n = 0
      logical :: refined = .false.
      type(patch_signature_t), allocatable :: sig(:)
      !> by level of the patch mesh (the coarse mesh for `refined`)
      type(level_ids_t), allocatable :: levels(:)
      !> open addressing on the keys while building: signature number or 0
      integer, allocatable :: hash(:)
   contains
      procedure :: init
      procedure :: add_mesh
      procedure :: finish
      procedure :: free => free_table
   end type patch_table_t

contains

   !> Every signature and factor goes: the table holds none, as before `init`.
   subroutine free_table(self)
      class(patch_table_t), intent(inout) :: self

      if (allocated(self%sig)) deallocate (self%sig)
      if (allocated(self%levels)) deallocate (self%levels)
      if (allocated(self%hash)) deallocate (self%hash)
      self%n = 0
   end subroutine free_table

   !> An empty table for patch meshes of levels 0..finest.
   subroutine init(self, refined, finest)
      class(patch_table_t), intent(out) :: self
      logical, intent(in) :: refined
      integer, intent(in) :: finest

      self%refined = refined
      allocate (self%sig(64), self%levels(0:finest), self%hash(256))
      self%hash = 0
   end subroutine init

   !> The triangles of the patch of vertex a of `mesh` (level `level`) in canonical order: by
   !> class, then local index of a, then number.
   pure subroutine patch_order(shapes, mesh, level, a, order)
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level
      integer(ip), intent(in) :: a
      integer(ip), intent(out) :: order(:)

      integer(ip) :: keys(max_patch), key, t
      integer :: n, k, j, class
      real(dp) :: ratio

      n = size(order)
      do k = 1, n
         t = mesh%patch_triangles(mesh%patch_ptr(a) + k - 1)
         call shapes%class_of(level, t, class, ratio)
         key = 4_ip*class + findloc(mesh%triangles(:, t), a, dim=1)
         ! insertion sort: patches have a handful of triangles
         j = k - 1
         do while (j >= 1)
            if (keys(j) < key .or. (keys(j) == key .and. order(j) < t)) exit
            keys(j + 1) = keys(j)
            order(j + 1) = order(j)
            j = j - 1
         end do
         keys(j + 1) = key
         order(j + 1) = t
      end do
   end subroutine patch_order

   !> The patch triangles of vertex a in canonical order (patch_order), from its code in a table
   !> (level_ids_t%order), or sorted here for a patch without one (code = no_code).
   pure subroutine stored_order(shapes, mesh, level, a, code, order)
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level, code
      integer(ip), intent(in) :: a
      integer(ip), intent(out) :: order(:)

      integer(ip) :: before
      integer :: k

      if (code == no_code) then
         call patch_order(shapes, mesh, level, a, order)
         return
      end if
      before = mesh%patch_ptr(a) - 1
      do k = 1, size(order)
         order(k) = mesh%patch_triangles(before + 1 + ibits(code, 3*(k - 1), 3))
      end do
   end subroutine stored_order

   !> The code of stored_order for the canonical order of the triangles of the patch of vertex a.
   pure integer function order_code(shapes, mesh, level, a) result(code)
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level
      integer(ip), intent(in) :: a

      integer(ip) :: order(max_coded), before
      integer :: n, k, position

      n = int(mesh%patch_ptr(a + 1) - mesh%patch_ptr(a))
      code = no_code
      if (n > max_coded) return
      call patch_order(shapes, mesh, level, a, order(1:n))
      before = mesh%patch_ptr(a) - 1
      code = 0
      do k = 1, n
         position = int(findloc(mesh%patch_triangles(before + 1:before + n), order(k), dim=1)) - 1
         code = ior(code, ishft(position, 3*(k - 1)))
      end do
   end function order_code

   !> trace_signs without a run-time-sized function result (no temporary per call): s(1:3 n_trace).
   pure subroutine edge_signs(n_trace, v, s)
      integer, intent(in) :: n_trace
      integer(ip), intent(in) :: v(3)
      real(dp), intent(out) :: s(:)

      s(1:3*n_trace) = 1.0_dp
      if (n_trace == 2) then
         if (v(2) > v(3)) s(2) = -1.0_dp
         if (v(3) > v(1)) s(4) = -1.0_dp
         if (v(1) > v(2)) s(6) = -1.0_dp
      end if
   end subroutine edge_signs

   !> Signatures of the patches of the vertices of `coarse` (level `level`) on its own triangles
   !> (`single`, with fine = coarse) or, for `refined`, on their children in `fine`.
   !> New signatures are factorized at `finish`. The vertices go in the order of their first
   !> patch triangle: red refinement numbers triangles along its tree, so consecutive patches
   !> in that order share their triangles' data in cache (key building waits on memory, not on
   !> arithmetic). The keys of a chunk are built
   !> and looked up among the known signatures in parallel; the new ones are then numbered in
   !> that order, so that the numbering does not depend on the threads.
   subroutine add_mesh(self, space, shapes, coarse, fine, level)
      class(patch_table_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_t), intent(in) :: coarse, fine
      integer, intent(in) :: level

      integer(ip), parameter :: chunk = 2048
      integer(ip) :: first, a, k, n
      integer :: width, n_coarse, n_children
      integer, allocatable :: keys(:, :), lengths(:), ids(:), codes(:)
      integer(i8), allocatable :: hashes(:)
      integer(ip), allocatable :: order(:)

      ! the longest key of this mesh (the buffer is set-up's peak on small meshes): ne, the local
      ! indices of the coarse triangles, and per triangle its class, zero-flux edge, three links
      ! and 3 n_trace signs (larger patches take the general path)
      n_children = merge(4, 1, self%refined)
      n_coarse = min(int(maxval(coarse%patch_ptr(2:) - coarse%patch_ptr(:coarse%nv))), max_patch/n_children)
      width = 1 + n_coarse + n_children*n_coarse*(5 + 3*space%n_trace)
      allocate (keys(width, chunk), lengths(chunk), hashes(chunk), ids(chunk), codes(chunk))
      allocate (self%levels(level)%id(coarse%nv), self%levels(level)%order(coarse%nv))
      self%levels(level)%id = 0
      self%levels(level)%order = no_code
      order = patch_vertices_by_first_triangle(coarse)
      n = size(order, kind=ip)
      do first = 1, n, chunk
         !$omp parallel do default(none) shared(self, space, shapes, coarse, fine, level, order, keys, lengths, hashes, ids) &
         !$omp shared(first, n, codes) private(k) schedule(dynamic, 64)
         do k = 1, min(chunk, n - first + 1)
            ids(k) = 0
            call patch_key(space, shapes, coarse, fine, level, self%refined, order(first + k - 1), keys(:, k), lengths(k))
            if (lengths(k) == 0) cycle
            codes(k) = order_code(shapes, coarse, level, order(first + k - 1))
            hashes(k) = key_hash(keys(1:lengths(k), k))
            ids(k) = self%hash(find(self%hash, self%sig, keys(1:lengths(k), k), hashes(k)))
         end do
         !$omp end parallel do
         do k = 1, min(chunk, n - first + 1)
            if (lengths(k) == 0) cycle
            a = order(first + k - 1)
            if (ids(k) == 0) ids(k) = lookup(self, keys(1:lengths(k), k), hashes(k), n_children)
            self%levels(level)%id(a) = ids(k)
            self%levels(level)%order(a) = codes(k)
         end do
      end do
   end subroutine add_mesh

   !> The vertices of the mesh whose patches are whole on this rank (on a rank's piece of a
   !> distributed mesh, the patches outside its subdomain are not), in the order of their first
   !> patch triangle (patches list their triangles in ascending order). Written as loops: this
   !> file's array temporaries live on the stack (CMakeLists.txt), and a mesh-sized one
   !> overflowed it at 4·10^6 vertices.
   function patch_vertices_by_first_triangle(mesh) result(order)
      type(mesh_t), intent(in) :: mesh
      integer(ip), allocatable :: order(:)

      logical, allocatable :: inside(:)
      integer(ip), allocatable :: all_vertices(:)
      integer(ip) :: k, n, a

      inside = mesh%in_subdomain()
      all_vertices = mesh%vertices_by_first_triangle()
      n = 0
      do a = 1, mesh%nv
         if (inside(a)) n = n + 1
      end do
      allocate (order(n))
      n = 0
      do k = 1, size(all_vertices, kind=ip)
         a = all_vertices(k)
         if (.not. inside(a)) cycle
         n = n + 1
         order(n) = a
      end do
   end function patch_vertices_by_first_triangle

   !> The key of the patch of vertex a (see add_mesh) in key(1:length): ne, the local indices of
   !> a in the coarse triangles, then per patch triangle its class, zero-flux edge, edge links
   !> (free ones included) and relative trace signs. length = 0: the patch takes the general
   !> path (too many triangles or multipliers for the fixed-size factors).
   pure subroutine patch_key(space, shapes, coarse, fine, level, refined, a, key, length)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_t), intent(in) :: coarse, fine
      integer, intent(in) :: level
      integer(ip), intent(in) :: a
      logical, intent(in) :: refined
      integer, intent(out) :: key(:), length

      integer :: n_coarse, n_children, ne, kc, c, m, k, i, n_inner, n_theta, l, child_level, nt
      integer(ip) :: order(max_patch), inner(9*max_patch), t, child, e
      integer :: classes(max_patch), neumann(max_patch), links(3, max_patch), local(max_patch)
      real(dp) :: signs(6, max_patch), o(2*9*max_patch), ratio

      length = 0
      n_children = merge(4, 1, refined)
      child_level = merge(level + 1, level, refined)
      nt = space%n_trace
      n_coarse = int(coarse%patch_ptr(a + 1) - coarse%patch_ptr(a))
      if (n_children*n_coarse > max_patch) return
      call patch_order(shapes, coarse, level, a, order(1:n_coarse))
      n_inner = 0
      if (refined) then
         ! the inner edges of each coarse triangle (its middle child's) first, one block each
         do kc = 1, n_coarse
            do m = 1, 3
               n_inner = n_inner + 1
               inner(n_inner) = fine%triangle_edges(m, 4*order(kc))
            end do
         end do
      end if
      ne = 0
      do kc = 1, n_coarse
         t = order(kc)
         local(kc) = findloc(coarse%triangles(:, t), a, dim=1)
         do c = 1, n_children
            ne = ne + 1
            child = merge(4*(t - 1) + c, t, refined)
            call shapes%class_of(child_level, child, classes(ne), ratio)
            call edge_signs(nt, fine%triangles(:, child), signs(:, ne))
            do m = 1, 3
               e = fine%triangle_edges(m, child)
               call link_edge(fine%boundary_edge(e), on_opposite_edge(refined, local(kc), c, m), &
                              coarse%boundary_vertex(a), e, inner, n_inner, links(m, ne))
            end do
            neumann(ne) = findloc(links(:, ne), edge_neumann, dim=1)
         end do
      end do
      ! relative signs: each multiplier oriented as in its first triangle
      n_theta = nt*n_inner
      if (n_theta > max_theta) return
      o(1:n_theta) = 0.0_dp
      do k = 1, ne
         do m = 1, 3
            if (links(m, k) <= 0) then
               ! not a multiplier of H (a zero-flux edge is condensed in its class's operators):
               ! its mesh orientation must not split signatures
               signs((m - 1)*nt + 1:m*nt, k) = 1.0_dp
               cycle
            end if
            do l = 1, nt
               i = (links(m, k) - 1)*nt + l
               if (o(i) == 0.0_dp) o(i) = signs((m - 1)*nt + l, k)
               signs((m - 1)*nt + l, k) = signs((m - 1)*nt + l, k)*o(i)
            end do
         end do
      end do
      length = 1 + n_coarse + ne*(5 + 3*nt)
      key(1) = ne
      key(2:1 + n_coarse) = local(1:n_coarse)
      i = 1 + n_coarse
      key(i + 1:i + ne) = classes(1:ne)
      key(i + ne + 1:i + 2*ne) = neumann(1:ne)
      i = i + 2*ne
      do k = 1, ne
         key(i + 1:i + 3) = links(:, k)
         i = i + 3
      end do
      ! the signs are ±1: stored exactly as integers
      do k = 1, ne
         key(i + 1:i + 3*nt) = merge(1, -1, signs(1:3*nt, k) > 0.0_dp)
         i = i + 3*nt
      end do
   end subroutine patch_key

   !> The signature of `key` (hash h = key_hash(key)), added if new; the classes, zero-flux edges
   !> and links of a new one are read from the key (n_children per coarse triangle).
   integer function lookup(self, key, h, n_children) result(id)
      type(patch_table_t), intent(inout) :: self
      integer, intent(in) :: key(:)
      integer(i8), intent(in) :: h
      integer, intent(in) :: n_children

      integer :: slot, ne, i
      type(patch_signature_t), allocatable :: grown(:)

      slot = find(self%hash, self%sig, key, h)
      id = self%hash(slot)
      if (id > 0) return
      self%n = self%n + 1
      id = self%n
      if (id > size(self%sig)) then
         allocate (grown(2*size(self%sig)))
         do i = 1, id - 1
            call move_signature(self%sig(i), grown(i))
         end do
         call move_alloc(grown, self%sig)
      end if
      ne = key(1)
      i = 1 + ne/n_children
      self%sig(id)%key = key
      self%sig(id)%corners = key(2:i)
      self%sig(id)%classes = key(i + 1:i + ne)
      self%sig(id)%neumann = key(i + ne + 1:i + 2*ne)
      self%sig(id)%links = reshape(key(i + 2*ne + 1:i + 5*ne), [3, ne])
      self%hash(slot) = id
      if (2*self%n > size(self%hash)) call rehash(self)
   end function lookup

   !> What a signature holds while the table is built, moved (no copy) from `from` to `to`.
   subroutine move_signature(from, to)
      type(patch_signature_t), intent(inout) :: from, to

      call move_alloc(from%classes, to%classes)
      call move_alloc(from%neumann, to%neumann)
      call move_alloc(from%links, to%links)
      call move_alloc(from%corners, to%corners)
      call move_alloc(from%key, to%key)
   end subroutine move_signature

   !> 32-bit FNV-1a over the key's integers, kept in 32 bits of a 64-bit integer so that the
   !> product never overflows (signed overflow is undefined, and the sanitizer build reports it).
   pure integer(i8) function key_hash(key) result(h)
      integer, intent(in) :: key(:)

      integer(i8), parameter :: mask32 = 4294967295_i8
      integer :: i

      h = 2166136261_i8
      do i = 1, size(key)
         h = ieor(h, iand(int(key(i), i8), mask32))
         h = iand(h*16777619_i8, mask32)
      end do
   end function key_hash

   !> The slot of key (hash h) in hash: its signature's, or the empty one where it belongs.
   pure integer function find(hash, sig, key, h) result(slot)
      integer, intent(in) :: hash(:)
      type(patch_signature_t), intent(in) :: sig(:)
      integer, intent(in) :: key(:)
      integer(i8), intent(in) :: h

      ! the hash modulo the power-of-two table size
      slot = int(iand(h, int(size(hash) - 1, i8))) + 1
      do
         if (hash(slot) == 0) return
         if (size(sig(hash(slot))%key) == size(key)) then
            if (all(sig(hash(slot))%key == key)) return
         end if
         slot = modulo(slot, size(hash)) + 1
      end do
   end function find

   subroutine rehash(self)
      type(patch_table_t), intent(inout) :: self

      integer :: id, n_slots

      ! a power of two: find takes the slot from the hash's low bits
      n_slots = 2*size(self%hash)
      do while (n_slots < 4*self%n)
         n_slots = 2*n_slots
      end do
      deallocate (self%hash)
      allocate (self%hash(n_slots))
      self%hash = 0
      do id = 1, self%n
         self%hash(find(self%hash, self%sig, self%sig(id)%key, key_hash(self%sig(id)%key))) = id
      end do
   end subroutine rehash

   !> Factorize the signatures (once: H is the same on every level) and drop the build data.
   subroutine finish(self, space, shapes, err)
      class(patch_table_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(error_t), allocatable, intent(out) :: err

      integer :: id, n_blocks
      logical :: ok, all_ok
      real(dp), allocatable :: signs(:, :)

      all_ok = .true.
      !$omp parallel do default(none) shared(self, space, shapes) private(id, n_blocks, ok, signs) &
      !$omp reduction(.and.:all_ok) schedule(dynamic, 8)
      do id = 1, self%n
         associate (s => self%sig(id))
            n_blocks = merge(size(s%classes)/4, 0, self%refined)
            call key_signs(s%key, size(s%classes), space%n_trace, signs)
            call condensed_factor(space, shapes, s%classes, signs, s%neumann, s%links, n_blocks, s%factor, ok)
            all_ok = all_ok .and. ok
            deallocate (s%key)
         end associate
      end do
      !$omp end parallel do
      ! the spare slots of `sig` stay: they hold nothing, and trimming the array would copy every
      ! factor
      if (allocated(self%hash)) deallocate (self%hash)
      if (.not. all_ok) call make_error(err, exit_io, 'estimators', 'a patch system is singular (degenerate triangles?)')
   end subroutine finish

   !> The relative signs stored at the end of a key.
   pure subroutine key_signs(key, ne, n_trace, signs)
      integer, intent(in) :: key(:), ne, n_trace
      real(dp), allocatable, intent(out) :: signs(:, :)

      allocate (signs(3*n_trace, ne))
      signs = reshape(real(key(size(key) - 3*n_trace*ne + 1:), dp), [3*n_trace, ne])
   end subroutine key_signs
end module twomem_estimate_patch_classes
