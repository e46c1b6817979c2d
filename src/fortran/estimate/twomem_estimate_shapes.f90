!> Shape classes of a red-refined hierarchy: every triangle of every level is a copy of its
!> coarse ancestor T_0, scaled by 2^−l, translated, and point-reflected when an odd number of
!> middle children lie on its line of descent (the corner children of refine_red are
!> homothetic copies with ratio 1/2, the middle child with ratio −1/2, local vertices keeping
!> their order). In the scaled monomial basis of twomem_estimate_raviart_thomas the mixed
!> matrices of similar triangles are the same up to powers of the ratio ρ = 2^l: with M the
!> mixed matrix, z and y the flux rows of M⁻¹ and C the edge traces, z ∝ ρ², y ∝ ρ, C ∝ ρ⁻¹, so
!> z Cᵀ ∝ ρ while C z Cᵀ and C y do not change, and the patch integrals of ψ_i against φ_j and
!> q_k scale with the area, ρ⁻². The trace rows of a triangle differ only by the sign of the
!> t-moment on the edges whose mesh orientation runs against the triangle's own. So one set of
!> operators per coarse triangle and reflection replaces the per-triangle inverses of every
!> level (about 270 numbers per triangle for RT1): the patch solvers scale and sign them on the
!> fly, and both membranes share them. `init` checks the similarity on every triangle, so a
!> hierarchy made otherwise is reported, not mis-estimated.
!> The scaled coordinates ξ = (x − x_K)/h_K (x_K the barycentre, h_K the longest edge, which
!> scales with 1/ρ) are the same function of the barycentric coordinates on every copy of a
!> class: the reflection is the class's own. So an integral over a triangle of a product of
!> monomials in ξ and barycentric coordinates is its class's times ρ⁻², and an L² projection
!> between such spaces (a Gram matrix's inverse times moments, both ∝ ρ⁻²) is its class's
!> unchanged; red refinement keeps the children's local order, so this holds from a triangle's
!> four children to it as well. The algebraic flux's P2 fields of r_α on the coarser meshes and
!> their patch data (twomem_estimate_alg_flux) come from these class operators, not quadrature;
!> for a refined patch, whose hat function ψ_a lives on the parent triangle, the moments on each
!> child are tabled per parent class, local vertex of a and child (child_*), so the patch loop
!> reads no coordinates.
module twomem_estimate_shapes
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t, red_children
   use twomem_linalg_dense, only: lu_factor, lu_solve
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, make_frame
   implicit none
   private

   public :: shape_classes_t, triangle_class, trace_signs, p2_monomials

   !> The dimension of P2, with the scaled monomials 1, ξ1, ξ2, ξ1², ξ1ξ2, ξ2² (p2_monomials).
   integer, parameter, public :: n_p2 = 6

   type :: shape_classes_t
      !> per class c = 2(T_0 − 1) + 1 (as T_0) or + 2 (point-reflected), at the size of T_0 and with
      !> every edge oriented by the class's own local order (t from local vertex m+1 to m+2):
      !> the operators of rt_space_t's patch solve, z (nf, nf), y (nf, nd), zc = z Cᵀ (nf, nc),
      !> czc = C z Cᵀ (nc, nc), cy = C y (nc, nd), the mass matrix (nf, nf) for the flux norms
      real(dp), allocatable :: z(:, :, :), y(:, :, :), zc(:, :, :), czc(:, :, :), cy(:, :, :), mass(:, :, :)
      !> patch integrals for the local vertex i of ψ_i: psi_phi(:, j, i) = ∫ ψ_i φ_j,
      !> psi_q(k, i) = ∫ ψ_i q_k, bary_psi_q(k, j, i) = ∫ λ_j ψ_i q_k, q_int(k) = ∫ q_k
      real(dp), allocatable :: psi_phi(:, :, :, :), psi_q(:, :, :), bary_psi_q(:, :, :, :), q_int(:, :)
      !> the same with the P2 monomials m_j for ψ_j: mono_psi_q(k, j, i) = ∫ m_j ψ_i q_k (∝ ρ⁻²)
      real(dp), allocatable :: mono_psi_q(:, :, :, :)
      !> L² projections, the same on every copy (see the module header): div_proj(:, j, i) holds
      !> the coefficients in the q_k of the projection of m_j ψ_i onto P_p; p2_from_p2(:, j, c)
      !> and p2_from_p1(:, j, c) those in the class's m_i of the projection onto P2 of the field
      !> that is m_j (resp. λ_j) of child c (refine_red's numbering, in the child's own frame and
      !> local order) on that child and zero on the other three
      real(dp), allocatable :: div_proj(:, :, :, :), p2_from_p2(:, :, :, :), p2_from_p1(:, :, :, :)
      !> the algebraic flux's patch data on the children of a triangle of the class, at the
      !> children's class size (∝ ρ_child⁻², ρ_child the children's ratio), with ψ_i the hat function
      !> of the parent's local vertex i and q_k, m_j, λ_j those of child c (refine_red's numbering):
      !> child_mono_psi_q(k, j, i, c) = ∫ m_j ψ_i q_k and child_bary_psi_q(k, j, i, c) = ∫ λ_j ψ_i q_k
      !> over child c, the moments of r ψ_i for r = m_j (resp. λ_j) on the child; child_q_coarse(k, l, c)
      !> = ∫ q_l^parent q_k over child c, those of a polynomial of P_p of the parent (the parent's q_l)
      real(dp), allocatable :: child_mono_psi_q(:, :, :, :, :), child_bary_psi_q(:, :, :, :, :)
      real(dp), allocatable :: child_q_coarse(:, :, :, :)
      !> the triangle condensed for a patch in which its edge i carries zero flux and the other
      !> two are inner edges (every triangle of an interior vertex's patch, with i the local
      !> index of the vertex; the children on the far edge of a refined patch): with N the trace
      !> rows of edge i, I those of the other two (edge i+1 first) and Z = zc(:, N) (C z Cᵀ)_NN⁻¹,
      !> cond_a = (C z Cᵀ)_II − (C z Cᵀ)_IN (C z Cᵀ)_NN⁻¹ (C z Cᵀ)_NI    (2 n_trace)²
      !> cond_qg = (C y)_I − (C z Cᵀ)_IN (C z Cᵀ)_NN⁻¹ (C y)_N       (2 n_trace, nd)
      !> cond_rg = y − Z (C y)_N                                      (nf, nd)
      !> cond_rt = zc(:, I) − Z (C z Cᵀ)_NI                           (nf, 2 n_trace)
      !> cond_qf = [zc(:, I)ᵀ − (C z Cᵀ)_IN (C z Cᵀ)_NN⁻¹ zc(:, N)ᵀ] Φ_iᵀ  (2 n_trace, 2)
      !> cond_rf = [z − Z zc(:, N)ᵀ] Φ_iᵀ                              (nf, 2)
      !> where Φ_i = psi_phi(:, :, i): the last two take a flux datum −μ ψ_i ∇u directly. They
      !> are stored side by side as the operators a patch solve applies to a triangle's data,
      !> cond_q = [cond_qg | cond_qf] and cond_r = [cond_rg | cond_rt | cond_rf], so that each
      !> takes one product (fewer, longer loops: this runs for every triangle of every patch);
      !> likewise y_zc = [y | zc] for a triangle with no zero-flux edge.
      real(dp), allocatable :: cond_a(:, :, :, :), cond_q(:, :, :, :), cond_r(:, :, :, :), y_zc(:, :, :)
      !> classes found by shape on a single mesh (`classify`), instead of one per coarse triangle:
      !> per triangle its class and ratio ρ to the class size, per shape its representative
      !> triangle (class 2k − 1 is representative k as it is, 2k its point reflection)
      integer, allocatable :: map(:)
      real(dp), allocatable :: ratio(:)
      integer(ip), allocatable :: representative(:)
   contains
      procedure :: classify
      procedure :: class_of
      procedure :: ratio_of
      procedure :: n_shapes
      procedure :: init
      procedure :: free
      procedure :: keep_mass_only
      procedure :: keep_factored_only
   end type shape_classes_t

contains

   !> The class of triangle t of level l (numbered as refine_red numbers children) and its
   !> ratio ρ = 2^l to the class size.
   pure subroutine triangle_class(level, t, class, ratio)
      integer, intent(in) :: level
      integer(ip), intent(in) :: t
      integer, intent(out) :: class
      real(dp), intent(out) :: ratio

      integer(ip) :: rest
      integer :: l, reflected

      rest = t - 1
      reflected = 0
      do l = 1, level
         ! child 4 of each step is the middle, point-reflected one
         if (modulo(rest, 4_ip) == 3) reflected = 1 - reflected
         rest = rest/4
      end do
      class = int(2*rest + 1 + reflected)
      ratio = 2.0_dp**level
   end subroutine triangle_class

   !> The class of triangle t of level l and its ratio ρ to the class size: by shape on a
   !> classified single mesh (classify), else as red refinement numbers it (triangle_class).
   pure subroutine class_of(self, level, t, class, ratio)
      class(shape_classes_t), intent(in) :: self
      integer, intent(in) :: level
      integer(ip), intent(in) :: t
      integer, intent(out) :: class
      real(dp), intent(out) :: ratio

      if (allocated(self%map)) then
         class = self%map(t)
         ratio = self%ratio(t)
      else
         call triangle_class(level, t, class, ratio)
      end if
   end subroutine class_of

   !> The ratio ρ of triangle t of level l to its class size (class_of's).
   pure real(dp) function ratio_of(self, level, t) result(ratio)
      class(shape_classes_t), intent(in) :: self
      integer, intent(in) :: level
      integer(ip), intent(in) :: t

      if (allocated(self%map)) then
         ratio = self%ratio(t)
      else
         ratio = 2.0_dp**level
      end if
   end function ratio_of

   !> The number of distinct shapes `classify` found (0 before, or when it gave up).
   pure integer function n_shapes(self)
      class(shape_classes_t), intent(in) :: self

      n_shapes = 0
      if (allocated(self%representative)) n_shapes = size(self%representative)
   end function n_shapes

   !> Classes by shape on a single mesh (a mesh without red-refined levels): two triangles share
   !> a class when one is a scaled and translated copy of the other with the local vertex order
   !> kept, or its point reflection (class 2k − 1 or 2k, as for red refinement), so that the
   !> class operators, patch signatures and factors serve every copy. Newest-vertex bisection
   !> makes finitely many similarity classes per initial triangle: an adapted mesh of 1.2·10^5
   !> triangles has about 600 shapes and 5·10^3 distinct patches for 6·10^4 vertices. A
   !> mesher's mesh has about one shape per triangle: past max_shapes the search stops and
   !> nothing is kept (the generic path then serves every patch). The key of a triangle: its
   !> offsets from the barycentre over its longest edge, with the sign that points the first
   !> vertex's offset to x > 0 (to y > 0 near the axis), rounded to 2^−30 and hashed to find
   !> candidates. A candidate is a copy if its offsets agree with the shape's first triangle to
   !> 10^−12 (round-off of bisection midpoints; a mesh file's 10^−11 near-copies stay apart):
   !> which triangle comes first depends on the partition, so a looser match would make the
   !> estimators depend on the rank count. Copies whose offsets round apart only make one
   !> shape more.
   subroutine classify(self, mesh, max_shapes)
      class(shape_classes_t), intent(inout) :: self
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: max_shapes

      real(dp), parameter :: quantum = 2.0_dp**30, axis = 1.0e-6_dp, copy_tol = 1.0e-12_dp
      integer(i8), parameter :: prime = 2147483647_i8
      integer(i8) :: key(6), h
      integer, allocatable :: table(:), shape_sign(:)
      real(dp), allocatable :: shape_size(:), shape_offsets(:, :)
      integer(ip), allocatable :: representative(:)
      integer(ip) :: t
      integer :: n_slots, slot, n, i, sgn, k
      real(dp) :: v(2, 3), centre(2), longest, offsets(6)

      if (allocated(self%map)) deallocate (self%map, self%ratio, self%representative)
      n_slots = 64
      do while (n_slots < 2*max_shapes)
         n_slots = 2*n_slots
      end do
      allocate (table(n_slots), shape_offsets(6, max_shapes), shape_sign(max_shapes), &
                shape_size(max_shapes), representative(max_shapes), self%map(mesh%nt), self%ratio(mesh%nt))
      table = 0
      n = 0
      do t = 1, mesh%nt
         v = mesh%vertices(:, mesh%triangles(:, t))
         centre = sum(v, dim=2)/3
         longest = max(norm2(v(:, 2) - v(:, 3)), norm2(v(:, 3) - v(:, 1)), norm2(v(:, 1) - v(:, 2)))
         do i = 1, 3
            v(:, i) = (v(:, i) - centre)/longest
         end do
         if (abs(v(1, 1)) > axis) then
            sgn = int(sign(1.0_dp, v(1, 1)))
         else
            sgn = int(sign(1.0_dp, v(2, 1)))
         end if
         offsets = sgn*reshape(v, [6])
         key = nint(quantum*offsets, i8)
         ! a polynomial hash kept below 2^51: no integer overflow
         h = 0
         do i = 1, 6
            h = modulo(h*1000003_i8 + key(i), prime)
         end do
         slot = int(iand(h, int(n_slots - 1, i8))) + 1
         do
            k = table(slot)
            if (k == 0) then
               n = n + 1
               if (n > max_shapes) then
                  deallocate (self%map, self%ratio)
                  return
               end if
               k = n
               table(slot) = k
               shape_offsets(:, k) = offsets
               shape_sign(k) = sgn
               shape_size(k) = longest
               representative(k) = t
               exit
            end if
            if (maxval(abs(offsets - shape_offsets(:, k))) <= copy_tol) exit
            slot = iand(slot, n_slots - 1) + 1
         end do
         self%map(t) = 2*k - merge(1, 0, sgn == shape_sign(k))
         self%ratio(t) = shape_size(k)/longest
      end do
      self%representative = representative(1:n)
   end subroutine classify

   !> ±1 per trace row of a triangle with mesh vertices v: −1 on the t-moment of an edge whose
   !> mesh orientation (from the lower vertex number) runs against the local one (m+1 to m+2).
   pure function trace_signs(space, v) result(s)
      type(rt_space_t), intent(in) :: space
      integer(ip), intent(in) :: v(3)
      real(dp) :: s(3*space%n_trace)

      integer :: m

      s = 1.0_dp
      if (space%n_trace == 2) then
         do m = 1, 3
            if (v(modulo(m, 3) + 1) > v(modulo(m + 1, 3) + 1)) s(2*m) = -1.0_dp
         end do
      end if
   end function trace_signs

   !> The classes of the hierarchy's coarse triangles. Without `multilevel` (default .true.) the
   !> tables only the multilevel algebraic flux reads (mono_psi_q, div_proj, the P2 projections,
   !> the children's moments: about half of a class) are neither computed nor stored.
   subroutine init(self, space, hierarchy, err, multilevel)
      class(shape_classes_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(error_t), allocatable, intent(out) :: err
      logical, intent(in), optional :: multilevel

      integer :: nf, nd, nc, n_classes, c, l, i, piv(space%n_flux + space%n_div)
      integer(ip) :: t0
      logical :: ok, all_ok, tables
      real(dp) :: v0(2, 3), centre(2), mass(space%n_flux, space%n_flux), div(space%n_div, space%n_flux)
      real(dp) :: mono(space%n_div, n_p2, 3)
      real(dp) :: trace(space%n_trace, space%n_flux, 3), c_rows(3*space%n_trace, space%n_flux)
      real(dp) :: mixed(space%n_flux + space%n_div, space%n_flux + space%n_div), inverse(size(mixed, 1), size(mixed, 1))
      type(rt_frame_t) :: frame

      call self%free(keep_shapes=.true.)
      tables = .true.
      if (present(multilevel)) tables = multilevel
      nf = space%n_flux
      nd = space%n_div
      nc = 3*space%n_trace
      if (allocated(self%map)) then
         n_classes = 2*self%n_shapes()
      else
         n_classes = int(2*hierarchy%meshes(0)%nt)
      end if
      block
         allocate (self%z(nf, nf, n_classes), self%y(nf, nd, n_classes), self%zc(nf, nc, n_classes), &
                   self%czc(nc, nc, n_classes), self%cy(nc, nd, n_classes), self%mass(nf, nf, n_classes))
         allocate (self%psi_phi(2, nf, 3, n_classes), self%psi_q(nd, 3, n_classes), &
                   self%bary_psi_q(nd, 3, 3, n_classes), self%q_int(nd, n_classes))
         if (tables) then
            allocate (self%mono_psi_q(nd, n_p2, 3, n_classes), self%div_proj(nd, n_p2, 3, n_classes), &
                      self%p2_from_p2(n_p2, n_p2, 4, n_classes), self%p2_from_p1(n_p2, 3, 4, n_classes))
            allocate (self%child_mono_psi_q(nd, n_p2, 3, 4, n_classes), self%child_bary_psi_q(nd, 3, 3, 4, n_classes), &
                      self%child_q_coarse(nd, nd, 4, n_classes))
         end if
         allocate (self%cond_a(nc - space%n_trace, nc - space%n_trace, 3, n_classes), &
                   self%cond_q(nc - space%n_trace, nd + 2, 3, n_classes), &
                   self%cond_r(nf, nd + nc - space%n_trace + 2, 3, n_classes), self%y_zc(nf, nd + nc, n_classes))
         all_ok = .true.
         !$omp parallel do default(none) shared(self, space, hierarchy, nf, nd, nc, n_classes, tables) &
         !$omp private(c, t0, v0, centre, frame, mass, div, trace, c_rows, mixed, inverse, piv, ok, i, l, mono) &
         !$omp reduction(.and.:all_ok) schedule(static)
         do c = 1, n_classes
            t0 = (c + 1)/2
            if (allocated(self%map)) t0 = self%representative(t0)
            v0 = hierarchy%meshes(0)%vertices(:, hierarchy%meshes(0)%triangles(:, t0))
            if (modulo(c, 2) == 0) then
               ! the point reflection through the barycentre, local order kept
               centre = sum(v0, dim=2)/3
               do i = 1, 3
                  v0(:, i) = 2*centre - v0(:, i)
               end do
            end if
            frame = make_frame(v0)
            call space%element_matrices(frame, [.true., .true., .true.], mass, div, trace)
            mixed = 0.0_dp
            mixed(1:nf, 1:nf) = mass
            mixed(nf + 1:, 1:nf) = div
            mixed(1:nf, nf + 1:) = transpose(div)
            inverse = 0.0_dp
            do i = 1, nf + nd
               inverse(i, i) = 1.0_dp
            end do
            call lu_factor(mixed, piv, ok)
            all_ok = all_ok .and. ok
            if (.not. ok) cycle
            call lu_solve(mixed, piv, inverse)
            do l = 1, 3
               c_rows((l - 1)*space%n_trace + 1:l*space%n_trace, :) = trace(:, :, l)
            end do
            self%mass(:, :, c) = mass
            self%z(:, :, c) = inverse(1:nf, 1:nf)
            self%y(:, :, c) = inverse(1:nf, nf + 1:)
            self%zc(:, :, c) = matmul(inverse(1:nf, 1:nf), transpose(c_rows))
            self%czc(:, :, c) = matmul(c_rows, self%zc(:, :, c))
            self%cy(:, :, c) = matmul(c_rows, inverse(1:nf, nf + 1:))
            self%y_zc(:, 1:nd, c) = self%y(:, :, c)
            self%y_zc(:, nd + 1:, c) = self%zc(:, :, c)
            call class_integrals(space, frame, self%psi_phi(:, :, :, c), self%psi_q(:, :, c), &
                                 self%bary_psi_q(:, :, :, c), self%q_int(:, c), mono)
            if (tables) then
               self%mono_psi_q(:, :, :, c) = mono
               call div_projection(space, frame, self%mono_psi_q(:, :, :, c), self%div_proj(:, :, :, c), ok)
               all_ok = all_ok .and. ok
               call children_projection(space, v0, self%p2_from_p2(:, :, :, c), self%p2_from_p1(:, :, :, c), ok)
               all_ok = all_ok .and. ok
               call children_moments(space, v0, self%child_mono_psi_q(:, :, :, :, c), &
                                     self%child_bary_psi_q(:, :, :, :, c), self%child_q_coarse(:, :, :, c))
            end if
            do i = 1, 3
               call condense(self, space, c, i, ok)
               all_ok = all_ok .and. ok
            end do
         end do
         !$omp end parallel do
      end block
      if (.not. all_ok) then
         call make_error(err, exit_io, 'estimators', 'a triangle''s mixed finite element matrix is singular')
         return
      end if
      do l = 1, hierarchy%levels
         if (.not. similar(hierarchy, l)) then
            call make_error(err, exit_io, 'estimators', 'the mesh hierarchy is not a red refinement of its coarse mesh')
            return
         end if
      end do
   end subroutine init

   !> The condensed operators cond_* of class c with zero flux on its edge i (see the type).
   pure subroutine condense(self, space, c, i, ok)
      type(shape_classes_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      integer, intent(in) :: c, i
      logical, intent(out) :: ok

      integer :: nt, nn, ni, nd, l, m, rows_n(space%n_trace), rows_i(2*space%n_trace), piv(space%n_trace)
      real(dp) :: schur(space%n_trace, space%n_trace), z_n(space%n_flux, space%n_trace)
      real(dp) :: x_ni(space%n_trace, 2*space%n_trace), x_ny(space%n_trace, space%n_div)
      real(dp) :: x_nf(space%n_trace, space%n_flux), phi(space%n_flux, 2)

      nt = space%n_trace
      nd = space%n_div
      nn = nt
      ni = 2*nt
      rows_n = [((i - 1)*nt + l, l=1, nt)]
      rows_i = [(((modulo(i + m - 1, 3))*nt + l, l=1, nt), m=1, 2)]
      associate (czc => self%czc(:, :, c), zc => self%zc(:, :, c), cy => self%cy(:, :, c), z => self%z(:, :, c), &
                 y => self%y(:, :, c))
         schur = czc(rows_n, rows_n)
         call lu_factor(schur, piv, ok)
         if (.not. ok) return
         ! (C z Cᵀ)_NN⁻¹ times the rows N of czc (inner columns), of cy and of zcᵀ
         x_ni = czc(rows_n, rows_i)
         x_ny = cy(rows_n, :)
         x_nf = transpose(zc(:, rows_n))
         call lu_solve(schur, piv, x_ni)
         call lu_solve(schur, piv, x_ny)
         call lu_solve(schur, piv, x_nf)
         z_n = zc(:, rows_n)
         phi = transpose(self%psi_phi(:, :, i, c))
         self%cond_a(:, :, i, c) = czc(rows_i, rows_i) - matmul(czc(rows_i, rows_n), x_ni)
         self%cond_q(:, 1:nd, i, c) = cy(rows_i, :) - matmul(czc(rows_i, rows_n), x_ny)
         self%cond_q(:, nd + 1:, i, c) = matmul(transpose(zc(:, rows_i)) - matmul(czc(rows_i, rows_n), x_nf), phi)
         self%cond_r(:, 1:nd, i, c) = y - matmul(z_n, x_ny)
         self%cond_r(:, nd + 1:nd + ni, i, c) = zc(:, rows_i) - matmul(z_n, x_ni)
         self%cond_r(:, nd + ni + 1:, i, c) = matmul(z - matmul(z_n, x_nf), phi)
      end associate
   end subroutine condense

   !> The integrals of psi_phi etc. (see the type) on one triangle, by the degree-5 rule (exact:
   !> m_j ψ_i q_k, the highest, is of degree 4).
   pure subroutine class_integrals(space, frame, psi_phi, psi_q, bary_psi_q, q_int, mono_psi_q)
      type(rt_space_t), intent(in) :: space
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(out) :: psi_phi(:, :, :), psi_q(:, :), bary_psi_q(:, :, :), q_int(:), mono_psi_q(:, :, :)

      real(dp) :: x(2), w, phi(2, space%n_flux), q(space%n_div), m(n_p2)
      integer :: k, i, j

      psi_phi = 0.0_dp
      psi_q = 0.0_dp
      bary_psi_q = 0.0_dp
      q_int = 0.0_dp
      mono_psi_q = 0.0_dp
      do k = 1, space%rule%n
         associate (bary => space%rule%bary(:, k))
            x = matmul(frame%vertices, bary)
            w = space%rule%weights(k)*frame%area
            phi = space%flux_values(frame, x)
            q = space%div_test_values(frame, x)
            m = p2_monomials(frame, x)
            q_int = q_int + w*q
            do i = 1, 3
               psi_phi(:, :, i) = psi_phi(:, :, i) + w*bary(i)*phi
               psi_q(:, i) = psi_q(:, i) + w*bary(i)*q
               do j = 1, 3
                  bary_psi_q(:, j, i) = bary_psi_q(:, j, i) + w*bary(j)*bary(i)*q
               end do
               do j = 1, n_p2
                  mono_psi_q(:, j, i) = mono_psi_q(:, j, i) + w*m(j)*bary(i)*q
               end do
            end do
         end associate
      end do
   end subroutine class_integrals

   !> div_proj (see the type): the Gram matrix of the q_k on the triangle solved against its
   !> moments mono_psi_q.
   pure subroutine div_projection(space, frame, mono_psi_q, div_proj, ok)
      type(rt_space_t), intent(in) :: space
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: mono_psi_q(:, :, :)
      real(dp), intent(out) :: div_proj(:, :, :)
      logical, intent(out) :: ok

      real(dp) :: gram(space%n_div, space%n_div), q(space%n_div), b(space%n_div, 3*n_p2)
      integer :: k, i, piv(space%n_div)

      gram = 0.0_dp
      do k = 1, space%rule%n
         q = space%div_test_values(frame, matmul(frame%vertices, space%rule%bary(:, k)))
         do i = 1, space%n_div
            gram(:, i) = gram(:, i) + space%rule%weights(k)*frame%area*q*q(i)
         end do
      end do
      b = reshape(mono_psi_q, shape(b))
      call lu_factor(gram, piv, ok)
      if (.not. ok) return
      call lu_solve(gram, piv, b)
      div_proj = reshape(b, shape(div_proj))
   end subroutine div_projection

   !> p2_from_p2 and p2_from_p1 (see the type) of the triangle with vertices v: the moments
   !> against the triangle's monomials of each child's monomials and barycentric coordinates
   !> (degree 4 at most: the rule is exact on each child), solved with the P2 Gram matrix.
   pure subroutine children_projection(space, v, p2_from_p2, p2_from_p1, ok)
      type(rt_space_t), intent(in) :: space
      real(dp), intent(in) :: v(2, 3)
      real(dp), intent(out) :: p2_from_p2(:, :, :), p2_from_p1(:, :, :)
      logical, intent(out) :: ok

      type(rt_frame_t) :: frame, child_frame
      real(dp) :: gram(n_p2, n_p2), x(2), w, m(n_p2), m_child(n_p2), children(2, 3, 4), b(n_p2, 9*4)
      integer :: k, c, j, piv(n_p2)

      frame = make_frame(v)
      children = red_children(v)
      gram = 0.0_dp
      p2_from_p2 = 0.0_dp
      p2_from_p1 = 0.0_dp
      do c = 1, 4
         child_frame = make_frame(children(:, :, c))
         do k = 1, space%rule%n
            x = matmul(child_frame%vertices, space%rule%bary(:, k))
            w = space%rule%weights(k)*child_frame%area
            m = p2_monomials(frame, x)
            m_child = p2_monomials(child_frame, x)
            do j = 1, n_p2
               gram(:, j) = gram(:, j) + w*m*m(j)
               p2_from_p2(:, j, c) = p2_from_p2(:, j, c) + w*m*m_child(j)
            end do
            do j = 1, 3
               p2_from_p1(:, j, c) = p2_from_p1(:, j, c) + w*m*space%rule%bary(j, k)
            end do
         end do
      end do
      b(:, 1:6*4) = reshape(p2_from_p2, [n_p2, 6*4])
      b(:, 6*4 + 1:) = reshape(p2_from_p1, [n_p2, 3*4])
      call lu_factor(gram, piv, ok)
      if (.not. ok) return
      call lu_solve(gram, piv, b)
      p2_from_p2 = reshape(b(:, 1:6*4), shape(p2_from_p2))
      p2_from_p1 = reshape(b(:, 6*4 + 1:), shape(p2_from_p1))
   end subroutine children_projection

   !> child_mono_psi_q, child_bary_psi_q and child_q_coarse (see the type) of the triangle with
   !> vertices v, by the degree-5 rule on each child (exact: degree 4 at most), times 4: at its
   !> class size a child is twice as large as v's child. ψ_i at a point of a child follows from
   !> the child's barycentric coordinates and its corners' in v (1, 1/2 or 0).
   pure subroutine children_moments(space, v, mono, bary, q_coarse)
      type(rt_space_t), intent(in) :: space
      real(dp), intent(in) :: v(2, 3)
      real(dp), intent(out) :: mono(:, :, :, :), bary(:, :, :, :), q_coarse(:, :, :)

      type(rt_frame_t) :: frame, child_frame
      real(dp) :: children(2, 3, 4), corners(2, 3, 4), x(2), w, lambda(3), psi(3), m(n_p2)
      real(dp) :: q(space%n_div), q_parent(space%n_div)
      integer :: c, k, i, j

      frame = make_frame(v)
      children = red_children(v)
      ! the first two barycentric coordinates in v of the children's corners: red_children of
      ! the triangle (1, 0), (0, 1), (0, 0) of those coordinates
      corners = red_children(reshape([1.0_dp, 0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 0.0_dp], [2, 3]))
      mono = 0.0_dp
      bary = 0.0_dp
      q_coarse = 0.0_dp
      do c = 1, 4
         child_frame = make_frame(children(:, :, c))
         do k = 1, space%rule%n
            lambda = space%rule%bary(:, k)
            x = matmul(child_frame%vertices, lambda)
            w = 4*space%rule%weights(k)*child_frame%area
            psi(1:2) = matmul(corners(:, :, c), lambda)
            psi(3) = 1.0_dp - psi(1) - psi(2)
            m = p2_monomials(child_frame, x)
            q = space%div_test_values(child_frame, x)
            q_parent = space%div_test_values(frame, x)
            do i = 1, 3
               do j = 1, n_p2
                  mono(:, j, i, c) = mono(:, j, i, c) + w*m(j)*psi(i)*q
               end do
               do j = 1, 3
                  bary(:, j, i, c) = bary(:, j, i, c) + w*lambda(j)*psi(i)*q
               end do
            end do
            do j = 1, space%n_div
               q_coarse(:, j, c) = q_coarse(:, j, c) + w*q_parent(j)*q
            end do
         end do
      end do
   end subroutine children_moments

   !> The scaled P2 monomials of a triangle's frame at x.
   pure function p2_monomials(frame, x) result(m)
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: x(2)
      real(dp) :: m(n_p2)

      real(dp) :: xi(2)

      xi = (x - frame%centre)/frame%scale
      m = [1.0_dp, xi(1), xi(2), xi(1)**2, xi(1)*xi(2), xi(2)**2]
   end function p2_monomials

   !> Whether every triangle of level l is its class's copy: vertices at ±2^−l times the
   !> class's offsets from the barycentre, to round-off of the coordinates.
   logical function similar(hierarchy, level) result(ok)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: level

      integer(ip) :: t, t0
      integer :: class, i
      real(dp) :: ratio, sign, v(2, 3), v0(2, 3), tolerance
      !> the coarse triangles' diameters, once (not per descendant)
      real(dp), allocatable :: h0(:)

      ok = .true.
      h0 = hierarchy%meshes(0)%diameter_of([(t0, t0=1, hierarchy%meshes(0)%nt)])
      !$omp parallel do default(none) shared(hierarchy, level, h0) &
      !$omp private(t, t0, class, ratio, sign, v, v0, tolerance, i) reduction(.and.:ok) schedule(static)
      do t = 1, hierarchy%meshes(level)%nt
         call triangle_class(level, t, class, ratio)
         t0 = (class + 1)/2
         sign = merge(-1.0_dp, 1.0_dp, modulo(class, 2) == 0)
         v = hierarchy%meshes(level)%vertices(:, hierarchy%meshes(level)%triangles(:, t))
         v0 = hierarchy%meshes(0)%vertices(:, hierarchy%meshes(0)%triangles(:, t0))
         tolerance = 1.0e-8_dp*h0(t0)/ratio
         do i = 1, 3
            ok = ok .and. all(abs((v(:, i) - sum(v, dim=2)/3) - sign/ratio*(v0(:, i) - sum(v0, dim=2)/3)) <= tolerance)
         end do
      end do
      !$omp end parallel do
   end function similar

   !> Once the patch signatures are factorized, when every patch without a signature takes the
   !> generic path (no refined level): the operators only a factorization or a patch assembled
   !> from its classes reads go (z, y, z Cᵀ, C z Cᵀ, the condensed multiplier blocks, the flux
   !> datum's integrals), about 40% of a class without the multilevel tables.
   subroutine keep_factored_only(self)
      class(shape_classes_t), intent(inout) :: self

      if (allocated(self%z)) deallocate (self%z, self%y, self%zc, self%czc)
      if (allocated(self%cond_a)) deallocate (self%cond_a)
      if (allocated(self%psi_phi)) deallocate (self%psi_phi)
   end subroutine keep_factored_only

   !> Once no patch is solved: everything but the mass matrices (the flux norms) goes.
   subroutine keep_mass_only(self)
      class(shape_classes_t), intent(inout) :: self

      real(dp), allocatable :: mass(:, :, :)

      if (allocated(self%mass)) call move_alloc(self%mass, mass)
      call self%free(keep_shapes=.true.)
      if (allocated(mass)) call move_alloc(mass, self%mass)
   end subroutine keep_mass_only

   !> Everything goes, but with keep_shapes the classification of `classify`.
   subroutine free(self, keep_shapes)
      class(shape_classes_t), intent(inout) :: self
      logical, intent(in), optional :: keep_shapes

      logical :: keep

      keep = .false.
      if (present(keep_shapes)) keep = keep_shapes
      if (.not. keep .and. allocated(self%map)) deallocate (self%map, self%ratio, self%representative)

      if (allocated(self%z)) deallocate (self%z, self%y, self%zc, self%czc)
      if (allocated(self%cy)) deallocate (self%cy)
      if (allocated(self%mass)) deallocate (self%mass)
      if (allocated(self%psi_phi)) deallocate (self%psi_phi)
      if (allocated(self%psi_q)) deallocate (self%psi_q, self%bary_psi_q, self%q_int)
      if (allocated(self%mono_psi_q)) deallocate (self%mono_psi_q, self%div_proj, self%p2_from_p2, self%p2_from_p1)
      if (allocated(self%child_mono_psi_q)) deallocate (self%child_mono_psi_q, self%child_bary_psi_q, self%child_q_coarse)
      if (allocated(self%cond_a)) deallocate (self%cond_a)
      if (allocated(self%cond_q)) deallocate (self%cond_q, self%cond_r, self%y_zc)
   end subroutine free
end module twomem_estimate_shapes
