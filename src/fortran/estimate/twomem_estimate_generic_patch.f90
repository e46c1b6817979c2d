!> The generic path of the vertex-patch problems (twomem_estimate_patch): every patch assembled,
!> factorized, solved for both membranes and discarded, its triangles' operators computed from
!> their vertices (twomem_estimate_triangle_ops), so that nothing is stored per triangle, per
!> shape class or per patch. A patch loop hands over one block of neighbouring patches at a
!> time (twomem_estimate_coloring): `gather` lists the block's distinct triangles and computes
!> each one's operators, and what the patches read of its mesh data (vertices, edges, trace
!> signs, P1 gradients), once into thread-private slots (a triangle lies in three patches,
!> mostly of the same block); the caller adds the iterate's values per slot (`fill`), solves
!> the block's patches one by one from the slots, each adding its σ to its triangles' slots,
!> and `flush` adds the slots' sums to the flux field. A mesh numbered without locality (a
!> mesher's) then costs one scattered access per triangle and block, not one per patch.
!> The hybridized solve is that of the general path, with the operators at the triangle's own
!> size (no ratio) and the flux datum σ_0 = ψ_i c entering through z Φ_iᵀ: each triangle's
!> particular solution σ_K = y G + z Φ_iᵀ c and its traces C σ_K, the zero-flux edge's rows
!> eliminated by their n_trace × n_trace Schur complement, the inner multipliers' SPD system
!> by Cholesky (its first multiplier pinned when no edge is free), then σ_K − z Cᵀ S μ. The
!> factorization depends on the geometry alone (factor_generic), the rest on the data
!> (solve_factored), so that a block holds two data sets side by side and one factorization
!> per patch serves both: the discretization flux and the one-level algebraic flux in one pass
!> (twomem_estimate_disc_flux). The work arrays grow to the largest patch seen and are kept by
!> the caller's scratch.
module twomem_estimate_generic_patch
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_patch, only: chol_factor, edge_free, edge_neumann, link_edge
   use twomem_estimate_patch_classes, only: edge_signs
   use twomem_estimate_triangle_ops, only: triangle_ops_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, gradients_on, lifting_on
   use twomem_fem_assembly, only: p1_gradients
   implicit none
   private

   !> data sets a gathered block holds side by side
   integer, parameter :: n_sets = 2

   public :: generic_scratch_t, solve_generic, factor_generic, solve_factored, patch_links

   !> One thread's scratch: the operators of a block's triangles, where each patch's triangles
   !> sit among them, and the work arrays of a patch solve.
   type :: generic_scratch_t
      !> the block's distinct triangles (ascending); ops slot k is triangles(k)
      integer(ip), allocatable :: triangles(:)
      integer :: n = 0
      type(triangle_ops_t) :: ops
      !> patch p of the gathered list (in the order given) has its triangles, in its patch list's
      !> order, in slots(first(p):first(p+1)−1); `table`: the hash table that finds them
      integer, allocatable :: first(:), slots(:), table(:)
      !> per slot: the triangle's vertices and edges, which edges lie on ∂Ω, its trace signs
      !> (twomem_estimate_shapes' trace_signs) and its P1 basis gradients
      integer(ip), allocatable :: vertices(:, :), edges(:, :)
      logical, allocatable :: on_boundary(:, :)
      real(dp), allocatable :: signs(:, :), hat(:, :, :)
      !> per slot and data set (two: the discretization and the algebraic flux may share a pass),
      !> from `fill`: a gradient per membrane (2, 2) and a lifting's vertex values (3, 2)
      real(dp), allocatable :: grad(:, :, :, :), lift(:, :, :, :)
      !> per slot and data set: the sum of its patches' σ, both membranes side by side
      !> (2, n_flux), for `flush`
      real(dp), allocatable :: sigma_sum(:, :, :, :)
      !> work arrays of factor_generic and solve_factored: the multiplier matrix (n_theta², column
      !> by column; its Cholesky factor), its right-hand sides (2, n_theta), per patch triangle
      !> its particular solution (2, n_flux), traces (2, 3 n_trace) and zero-flux block's inverse
      real(dp), allocatable :: h(:), b(:, :), part(:, :, :), c_sigma(:, :, :), inv_n(:, :, :)
      !> the factorized patch's multiplier count, and whether its first multiplier is pinned
      integer :: n_theta = 0
      logical :: pinned = .false.
   contains
      procedure :: gather
      procedure :: fill
      procedure :: flush
      procedure :: ensure
      procedure :: free
   end type generic_scratch_t

contains

   !> The operators of every triangle of the patches of `vertices` of `mesh` (whole patches:
   !> vertices of the rank's own triangles), each computed once, in the order the patches first
   !> meet them. ok is .false. if one is degenerate.
   subroutine gather(self, space, mesh, vertices, ok)
      class(generic_scratch_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: vertices(:)
      logical, intent(out) :: ok

      integer :: p, n_entries, k, s, i, n_slots, slot
      integer(ip) :: a, t
      real(dp) :: v(2, 3)
      logical :: one_ok

      n_entries = 0
      do p = 1, size(vertices)
         a = vertices(p)
         n_entries = n_entries + int(mesh%patch_ptr(a + 1) - mesh%patch_ptr(a))
      end do
      call grow(self%first, size(vertices) + 1)
      call grow(self%slots, n_entries)
      ! the distinct triangles by open addressing on their numbers (a power-of-two table at most
      ! half full: the slot from the number's low bits, then the next free one)
      n_slots = 64
      do while (n_slots < 2*n_entries)
         n_slots = 2*n_slots
      end do
      call grow(self%table, n_slots)
      self%table(1:n_slots) = 0
      if (allocated(self%triangles)) then
         if (size(self%triangles) < n_entries) deallocate (self%triangles)
      end if
      if (.not. allocated(self%triangles)) allocate (self%triangles(n_entries))
      s = 0
      k = 0
      do p = 1, size(vertices)
         a = vertices(p)
         self%first(p) = k + 1
         do i = int(mesh%patch_ptr(a)), int(mesh%patch_ptr(a + 1) - 1)
            t = mesh%patch_triangles(i)
            slot = int(iand(int(t, i8)*2654435761_i8, int(n_slots - 1, i8))) + 1
            do
               if (self%table(slot) == 0) then
                  s = s + 1
                  self%triangles(s) = t
                  self%table(slot) = s
                  exit
               end if
               if (self%triangles(self%table(slot)) == t) exit
               slot = iand(slot, n_slots - 1) + 1
            end do
            k = k + 1
            self%slots(k) = self%table(slot)
         end do
      end do
      self%first(size(vertices) + 1) = k + 1
      self%n = s
      call self%ops%reserve(space, s)
      call reserve_slots(self, space, s)
      ok = .true.
      do s = 1, self%n
         t = self%triangles(s)
         do i = 1, 3
            self%vertices(i, s) = mesh%triangles(i, t)
            self%edges(i, s) = mesh%triangle_edges(i, t)
            self%on_boundary(i, s) = mesh%boundary_edge(self%edges(i, s))
            v(:, i) = mesh%vertices(:, self%vertices(i, s))
         end do
         call edge_signs(space%n_trace, self%vertices(:, s), self%signs(:, s))
         self%hat(:, :, s) = p1_gradients(mesh, t)
         self%sigma_sum(:, :, s, :) = 0.0_dp
         call self%ops%compute(space, s, v, one_ok)
         ok = ok .and. one_ok
      end do
   end subroutine gather

   !> Per-slot arrays for n triangles (kept when there is room).
   pure subroutine reserve_slots(self, space, n)
      type(generic_scratch_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      integer, intent(in) :: n

      if (allocated(self%vertices)) then
         if (size(self%vertices, 2) >= n .and. size(self%sigma_sum, 2) == space%n_flux) return
         deallocate (self%vertices, self%edges, self%on_boundary, self%signs, self%hat, self%grad, self%lift, &
                     self%sigma_sum)
      end if
      allocate (self%vertices(3, n), self%edges(3, n), self%on_boundary(3, n), self%signs(3*space%n_trace, n), &
                self%hat(2, 3, n), self%grad(2, 2, n, n_sets), self%lift(3, 2, n, n_sets), &
                self%sigma_sum(2, space%n_flux, n, n_sets))
   end subroutine reserve_slots

   !> grad(:, :, s, set) = ∇u_α and lift(:, :, s, set) = the residual lifting's vertex values
   !> of `source` on every gathered triangle (its u and shares: an evaluated iterate, or the
   !> Riesz representer of twomem_estimate_riesz); set: the data set (1 or 2).
   subroutine fill(self, mesh, source, set)
      class(generic_scratch_t), intent(inout) :: self
      type(mesh_t), intent(in) :: mesh
      type(evaluated_iterate_t), intent(in) :: source
      integer, intent(in) :: set

      integer :: s

      do s = 1, self%n
         call gradients_on(source, mesh, self%triangles(s), self%hat(:, :, s), self%grad(:, :, s, set))
         call lifting_on(source, mesh, self%triangles(s), self%lift(:, :, s, set))
      end do
   end subroutine fill

   !> sigma(:, t, α) += the slots' sums of data set `set`: each gathered triangle's share of the
   !> block's patches.
   subroutine flush(self, sigma, set)
      class(generic_scratch_t), intent(in) :: self
      real(dp), intent(inout) :: sigma(:, :, :)
      integer, intent(in) :: set

      integer :: s
      integer(ip) :: t

      do s = 1, self%n
         t = self%triangles(s)
         sigma(:, t, 1) = sigma(:, t, 1) + self%sigma_sum(1, :, s, set)
         sigma(:, t, 2) = sigma(:, t, 2) + self%sigma_sum(2, :, s, set)
      end do
   end subroutine flush

   !> The local vertex of patch vertex a (corner(k)) in each triangle of the p-th gathered patch
   !> and its edges' links (solve_patch's links; twomem_estimate_patch%link_edge), from the slots.
   pure subroutine patch_links(scratch, p, a, a_on_boundary, corner, links)
      type(generic_scratch_t), intent(in) :: scratch
      integer, intent(in) :: p
      integer(ip), intent(in) :: a
      logical, intent(in) :: a_on_boundary
      integer, intent(out) :: corner(:), links(:, :)

      integer(ip) :: inner(2*size(corner) + 2)
      integer :: k, m, n_inner, s, i

      n_inner = 0
      do k = 1, size(corner)
         s = scratch%slots(scratch%first(p) + k - 1)
         i = 1
         do while (scratch%vertices(i, s) /= a)
            i = i + 1
         end do
         corner(k) = i
         do m = 1, 3
            call link_edge(scratch%on_boundary(m, s), m == i, a_on_boundary, scratch%edges(m, s), inner, n_inner, &
                           links(m, k))
         end do
      end do
   end subroutine patch_links

   !> An integer array of at least n entries (kept when it has them).
   pure subroutine grow(x, n)
      integer, allocatable, intent(inout) :: x(:)
      integer, intent(in) :: n

      if (allocated(x)) then
         if (size(x) >= n) return
         deallocate (x)
      end if
      allocate (x(n))
   end subroutine grow

   !> Work arrays for a patch of ne triangles and n_theta multipliers.
   pure subroutine ensure(self, space, ne, n_theta)
      class(generic_scratch_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      integer, intent(in) :: ne, n_theta

      integer :: nc

      nc = 3*space%n_trace
      if (allocated(self%h)) then
         if (size(self%b, 2) < n_theta .or. size(self%part, 3) < ne .or. size(self%part, 2) /= space%n_flux) &
            deallocate (self%h, self%b, self%part, self%c_sigma, self%inv_n)
      end if
      ! room for a little more than asked: the next patches are about as large
      if (.not. allocated(self%h)) allocate (self%h(max(n_theta + 8, 1)**2), self%b(2, max(n_theta + 8, 1)), &
                                             self%part(2, space%n_flux, ne + 4), self%c_sigma(2, nc, ne + 4), &
                                             self%inv_n(space%n_trace, space%n_trace, ne + 4))
   end subroutine ensure

   subroutine free(self)
      class(generic_scratch_t), intent(inout) :: self

      if (allocated(self%triangles)) deallocate (self%triangles)
      if (allocated(self%first)) deallocate (self%first)
      if (allocated(self%slots)) deallocate (self%slots)
      if (allocated(self%table)) deallocate (self%table)
      if (allocated(self%h)) deallocate (self%h, self%b, self%part, self%c_sigma, self%inv_n)
      if (allocated(self%vertices)) deallocate (self%vertices, self%edges, self%on_boundary, self%signs, self%hat, &
                                                self%grad, self%lift, self%sigma_sum)
      if (allocated(self%ops%y)) deallocate (self%ops%y, self%ops%zc, self%ops%czc, self%ops%trace, self%ops%z_phi, &
                                             self%ops%psi_q, self%ops%bary_psi_q, self%ops%q_int)
      self%ops%capacity = 0
      self%n = 0
   end subroutine free

   !> One patch from the gathered operators, for one set of data: factor_generic, then
   !> solve_factored for set 1 (see both).
   pure subroutine solve_generic(space, scratch, slots, corner, links, fgrad, rhs_div, flux_data, ok)
      type(rt_space_t), intent(in) :: space
      type(generic_scratch_t), intent(inout) :: scratch
      integer, intent(in) :: slots(:), corner(:), links(:, :)
      real(dp), intent(in) :: fgrad(:, :, :), rhs_div(:, :, :)
      logical, intent(in) :: flux_data
      logical, intent(out) :: ok

      call factor_generic(space, scratch, slots, links, ok)
      if (ok) call solve_factored(space, scratch, slots, corner, links, fgrad, rhs_div, flux_data, 1)
   end subroutine solve_generic

   !> The multiplier system of one patch from the gathered operators, factorized: patch
   !> triangle k is slot slots(k), links(m, k) as in solve_patch (inner edge > 0, edge_free,
   !> edge_neumann); the slot's trace signs turn its local trace rows into the mesh's
   !> orientation. It depends on the geometry alone, so that every data set of the patch
   !> (solve_factored) shares it. ok is .false. if it is singular. Written with explicit loops
   !> over the rows (no array sections with vector subscripts: each would be a temporary per
   !> use), the matrix in a contiguous buffer that the Cholesky factorization takes as it is.
   pure subroutine factor_generic(space, scratch, slots, links, ok)
      type(rt_space_t), intent(in) :: space
      type(generic_scratch_t), intent(inout) :: scratch
      integer, intent(in) :: slots(:), links(:, :)
      logical, intent(out) :: ok

      integer, parameter :: mc = 6, mt = 2
      integer :: nt, nc, ne, n, k, s, i, j, q, nn, ni, l, c0
      integer :: rows_n(mt), rows_i(mc), glob(mc)
      real(dp) :: czc(mc, mc), sg(mc), acc, x(mt, mc)

      nt = space%n_trace
      nc = 3*nt
      ne = size(slots)
      n = nt*max(0, maxval(links))
      call scratch%ensure(space, ne, n)
      scratch%n_theta = n
      associate (ops => scratch%ops, h => scratch%h, inv_n => scratch%inv_n)
         h(1:n*n) = 0.0_dp
         ok = .true.
         do k = 1, ne
            s = slots(k)
            do i = 1, nc
               sg(i) = scratch%signs(i, s)
            end do
            do j = 1, nc
               do i = 1, nc
                  czc(i, j) = sg(i)*sg(j)*ops%czc(i, j, s)
               end do
            end do
            call split_rows(links(:, k), nt, nn, rows_n, ni, rows_i, glob)
            if (nn > 0) then
               ! zero flux through the patch boundary: the edge's rows by their Schur complement
               call small_inverse(nt, czc, rows_n, inv_n(:, :, k), ok)
               if (.not. ok) return
               ! x = N⁻¹ czc(n, inner)
               do j = 1, ni
                  do l = 1, nn
                     acc = 0.0_dp
                     do q = 1, nn
                        acc = acc + inv_n(l, q, k)*czc(rows_n(q), rows_i(j))
                     end do
                     x(l, j) = acc
                  end do
               end do
               do j = 1, ni
                  c0 = (glob(j) - 1)*n
                  do i = 1, ni
                     acc = czc(rows_i(i), rows_i(j))
                     do q = 1, nn
                        acc = acc - czc(rows_i(i), rows_n(q))*x(q, j)
                     end do
                     h(c0 + glob(i)) = h(c0 + glob(i)) + acc
                  end do
               end do
            else
               do j = 1, ni
                  c0 = (glob(j) - 1)*n
                  do i = 1, ni
                     h(c0 + glob(i)) = h(c0 + glob(i)) + czc(rows_i(i), rows_i(j))
                  end do
               end do
            end if
         end do
         if (n > 0) then
            scratch%pinned = .not. any(links == edge_free)
            if (scratch%pinned) then
               ! only zero-flux boundary: θ is defined up to a constant, pin the first multiplier
               do i = 1, n
                  h(i) = 0.0_dp
                  h((i - 1)*n + 1) = 0.0_dp
               end do
               h(1) = 1.0_dp
            end if
            call chol_factor(n, h(1:n*n), ok)
         end if
      end associate
   end subroutine factor_generic

   !> One data set of the patch whose system factor_generic has just factorized (the same
   !> slots and links): for both membranes r, fgrad(:, k, r) the constant c of the flux datum
   !> ψ_a c (read when flux_data), rhs_div(:, k, r) the divergence moments, corner(k) the patch
   !> vertex's local vertex in triangle k; σ on triangle k is added to its slot's sum of data
   !> set `set`. The particular solution σ_K = y G + z Φ_iᵀ c of each triangle and its traces
   !> S C σ_K, the zero-flux edge's rows eliminated as in the factorization, the multipliers
   !> from the factor, then σ_K − z Cᵀ S μ. The two membranes' values side by side (each
   !> operator entry read once for both, the pair one vector operation).
   pure subroutine solve_factored(space, scratch, slots, corner, links, fgrad, rhs_div, flux_data, set)
      type(rt_space_t), intent(in) :: space
      type(generic_scratch_t), intent(inout) :: scratch
      integer, intent(in) :: slots(:), corner(:), links(:, :)
      real(dp), intent(in) :: fgrad(:, :, :), rhs_div(:, :, :)
      logical, intent(in) :: flux_data
      integer, intent(in) :: set

      integer, parameter :: mc = 6, mt = 2
      integer :: nt, nf, nd, nc, ne, n, k, s, i, q, nn, ni, l, m, ci
      integer :: rows_n(mt), rows_i(mc), glob(mc)
      real(dp) :: sg(mc), acc2(2), xr(2, mt), mu(2, mc), part(2, 8), g2(2, 3), f2(2, 2)

      nt = space%n_trace
      nf = space%n_flux
      nd = space%n_div
      nc = 3*nt
      ne = size(slots)
      n = scratch%n_theta
      associate (ops => scratch%ops, h => scratch%h, b => scratch%b, c_sigma => scratch%c_sigma, inv_n => scratch%inv_n)
         b(:, 1:n) = 0.0_dp
         do k = 1, ne
            s = slots(k)
            ci = corner(k)
            do i = 1, nc
               sg(i) = scratch%signs(i, s)
            end do
            do q = 1, nd
               g2(:, q) = rhs_div(q, k, :)
            end do
            ! the triangle alone: σ = y G + z Φ_iᵀ c, its traces S C σ
            if (flux_data) then
               f2(:, 1) = fgrad(1, k, :)
               f2(:, 2) = fgrad(2, k, :)
               do i = 1, nf
                  acc2 = ops%z_phi(i, 1, ci, s)*f2(:, 1) + ops%z_phi(i, 2, ci, s)*f2(:, 2)
                  do q = 1, nd
                     acc2 = acc2 + ops%y(i, q, s)*g2(:, q)
                  end do
                  part(:, i) = acc2
               end do
            else
               do i = 1, nf
                  acc2 = 0.0_dp
                  do q = 1, nd
                     acc2 = acc2 + ops%y(i, q, s)*g2(:, q)
                  end do
                  part(:, i) = acc2
               end do
            end if
            scratch%part(:, 1:nf, k) = part(:, 1:nf)
            do i = 1, nc
               acc2 = 0.0_dp
               do q = 1, nf
                  acc2 = acc2 + ops%trace(i, q, s)*part(:, q)
               end do
               c_sigma(:, i, k) = sg(i)*acc2
            end do
            call split_rows(links(:, k), nt, nn, rows_n, ni, rows_i, glob)
            if (nn > 0) then
               ! xr = N⁻¹ S C σ(n), then the Schur complement's right-hand side
               do l = 1, nn
                  acc2 = 0.0_dp
                  do q = 1, nn
                     acc2 = acc2 + inv_n(l, q, k)*c_sigma(:, rows_n(q), k)
                  end do
                  xr(:, l) = acc2
               end do
               do i = 1, ni
                  acc2 = c_sigma(:, rows_i(i), k)
                  do q = 1, nn
                     acc2 = acc2 - (sg(rows_i(i))*sg(rows_n(q))*ops%czc(rows_i(i), rows_n(q), s))*xr(:, q)
                  end do
                  b(:, glob(i)) = b(:, glob(i)) + acc2
               end do
            else
               do i = 1, ni
                  b(:, glob(i)) = b(:, glob(i)) + c_sigma(:, rows_i(i), k)
               end do
            end if
         end do
         if (n > 0) then
            if (scratch%pinned) b(:, 1) = 0.0_dp
            call paired_solve(n, h(1:n*n), b(:, 1:n))
         end if
         ! σ_K = particular − z Cᵀ S μ, μ: θ on inner rows, the solved zero-flux rows, 0 on free rows
         do k = 1, ne
            s = slots(k)
            do i = 1, nc
               sg(i) = scratch%signs(i, s)
            end do
            call split_rows(links(:, k), nt, nn, rows_n, ni, rows_i, glob)
            mu(:, 1:nc) = 0.0_dp
            do i = 1, ni
               mu(:, rows_i(i)) = b(:, glob(i))
            end do
            if (nn > 0) then
               do l = 1, nn
                  acc2 = c_sigma(:, rows_n(l), k)
                  do i = 1, ni
                     acc2 = acc2 - (sg(rows_n(l))*sg(rows_i(i))*ops%czc(rows_n(l), rows_i(i), s))*mu(:, rows_i(i))
                  end do
                  xr(:, l) = acc2
               end do
               do l = 1, nn
                  acc2 = 0.0_dp
                  do q = 1, nn
                     acc2 = acc2 + inv_n(l, q, k)*xr(:, q)
                  end do
                  mu(:, rows_n(l)) = acc2
               end do
            end if
            do m = 1, nc
               mu(:, m) = sg(m)*mu(:, m)
            end do
            do i = 1, nf
               acc2 = scratch%part(:, i, k)
               do m = 1, nc
                  acc2 = acc2 - ops%zc(i, m, s)*mu(:, m)
               end do
               scratch%sigma_sum(:, i, s, set) = scratch%sigma_sum(:, i, s, set) + acc2
            end do
         end do
      end associate
   end subroutine solve_factored

   !> b = (L Lᵀ)⁻¹ b for two right-hand sides side by side (b(r, i): right-hand side r, unknown
   !> i), with the factor of chol_factor: each entry of L read once for both.
   pure subroutine paired_solve(n, a, b)
      integer, intent(in) :: n
      real(dp), intent(in) :: a(n, n)
      real(dp), intent(inout) :: b(:, :)

      integer :: i, k
      real(dp) :: x(2)

      do k = 1, n
         x = b(:, k)/a(k, k)
         b(:, k) = x
         do i = k + 1, n
            b(:, i) = b(:, i) - a(i, k)*x
         end do
      end do
      do k = n, 1, -1
         x = b(:, k)
         do i = k + 1, n
            x = x - a(i, k)*b(:, i)
         end do
         b(:, k) = x/a(k, k)
      end do
   end subroutine paired_solve

   !> The trace rows of one patch triangle: nn on its zero-flux edge, ni on inner edges with
   !> their patch multipliers glob.
   pure subroutine split_rows(links, nt, nn, rows_n, ni, rows_i, glob)
      integer, intent(in) :: links(3), nt
      integer, intent(out) :: nn, rows_n(:), ni, rows_i(:), glob(:)

      integer :: m, l

      nn = 0
      ni = 0
      do m = 1, 3
         do l = 1, nt
            if (links(m) == edge_neumann) then
               nn = nn + 1
               rows_n(nn) = (m - 1)*nt + l
            else if (links(m) > 0) then
               ni = ni + 1
               rows_i(ni) = (m - 1)*nt + l
               glob(ni) = (links(m) - 1)*nt + l
            end if
         end do
      end do
   end subroutine split_rows

   !> inv = the inverse of a(rows, rows) for n = 1 or 2 rows (the zero-flux edge's block: SPD).
   pure subroutine small_inverse(n, a, rows, inv, ok)
      integer, intent(in) :: n, rows(:)
      real(dp), intent(in) :: a(:, :)
      real(dp), intent(out) :: inv(:, :)
      logical, intent(out) :: ok

      real(dp) :: det, a11, a12, a21, a22

      if (n == 1) then
         a11 = a(rows(1), rows(1))
         ok = a11 > 0.0_dp
         if (ok) inv(1, 1) = 1/a11
         return
      end if
      a11 = a(rows(1), rows(1))
      a12 = a(rows(1), rows(2))
      a21 = a(rows(2), rows(1))
      a22 = a(rows(2), rows(2))
      det = a11*a22 - a12*a21
      ok = det > 0.0_dp .and. a11 > 0.0_dp
      if (.not. ok) return
      inv(1, 1) = a22/det
      inv(2, 2) = a11/det
      inv(1, 2) = -a12/det
      inv(2, 1) = -a21/det
   end subroutine small_inverse
end module twomem_estimate_generic_patch
