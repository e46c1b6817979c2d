!> The factored path of the patch problems of twomem_estimate_patch: the multiplier matrix H of
!> a patch depends only on its triangles' shape classes, edges and relative trace orientations,
!> so the patches that have the same ones (a signature, twomem_estimate_patch_classes) share one
!> factor of H, computed once at set-up; an evaluation only assembles each patch's right-hand
!> sides, applies the factor and forms the triangles' fluxes with the class operators. Both
!> membranes share every operator and factor, so a patch is solved for the two at once, their
!> values side by side, each stored number read once for both (mat_vec).
module twomem_estimate_patch_factor
   use twomem_base_kinds, only: dp, ip
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_patch, only: edge_free, chol_factor, chol_solve
   implicit none
   private

   public :: patch_factor_t, condensed_factor, solve_condensed_factored, max_theta

   !> the largest multiplier system of a factorized patch (larger ones take the general path),
   !> so that the per-patch work arrays have fixed sizes (no heap allocation per patch)
   integer, parameter :: max_theta = 192
   !> the slot of solve_condensed_factored's multiplier vector that the trace rows of free edges
   !> (on ∂Ω: no multiplier) point to: their products land there and are dropped, and zero is
   !> read back, so the per-triangle loops have no branch
   integer, parameter :: free_slot = max_theta + 1

   !> The multiplier matrix H of a condensed patch system, factorized once for every patch with
   !> the same classes, edges and relative trace signs (twomem_estimate_patch_classes): H does
   !> not depend on the ratio of the triangles nor on the data, only the right-hand side does.
   !> d: the inverses of the n_blocks leading diagonal blocks (size g), x = D⁻¹ H_bt on the
   !> tail columns cols(1:n_cols) each block touches, s: the inverse of the tail's Schur
   !> complement (of the whole H when n_blocks = 0). Inverses, not Cholesky factors: the factor
   !> serves thousands of patches, and a product with an inverse has no chain of dependent
   !> operations, unlike the two triangular substitutions.
   !> Both products of block_apply with x take its columns whole, times both membranes' values
   !> at once (a transposed copy of x for the tail update held 13 MB at 10⁶ vertices).
   type :: patch_factor_t
      integer :: n_theta = 0, n_blocks = 0, g = 0
      !> the first multiplier is pinned to zero (no free edge: θ is defined up to a constant)
      logical :: pinned = .true.
      real(dp), allocatable :: d(:, :, :), x(:, :, :), s(:, :)
      integer, allocatable :: cols(:, :), n_cols(:)
      !> per patch triangle: its inner trace rows and their multipliers (inner_rows), and the
      !> relative trace sign of each (the signature's, which every patch of it has: see
      !> solve_condensed_factored)
      integer, allocatable :: n_rows(:), rows(:, :), glob(:, :)
      real(dp), allocatable :: sg(:, :)
   end type patch_factor_t

contains

   !> The factor of the multiplier matrix H of a patch, with the triangles condensed by their
   !> class (twomem_estimate_shapes, cond_*): neumann(k) is the edge of triangle k that carries
   !> zero flux, or 0 when none does; links(m, k) numbers the inner edges (edge_free: on ∂Ω, no
   !> multiplier). H is assembled with the patch's relative trace signs (each multiplier
   !> oriented as in the first triangle that touches it, so that H depends on the geometry
   !> only). Without a free edge (an interior vertex's patch) the multipliers are defined up to
   !> a constant, and the first one is pinned.
   pure subroutine condensed_factor(space, shapes, classes, signs, neumann, links, n_blocks, factor, ok)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      integer, intent(in) :: classes(:), neumann(:), links(:, :)
      real(dp), intent(in) :: signs(:, :)
      integer, intent(in) :: n_blocks
      type(patch_factor_t), intent(out) :: factor
      logical, intent(out) :: ok

      integer :: nt, k, c, i, a, q, n_rows, rows(3*space%n_trace), glob(3*space%n_trace)
      real(dp) :: h(space%n_trace*maxval(links), space%n_trace*maxval(links))
      real(dp) :: sg(3*space%n_trace), a_k(3*space%n_trace, 3*space%n_trace)
      logical :: pinned

      nt = space%n_trace
      h = 0.0_dp
      do k = 1, size(classes)
         c = classes(k)
         call inner_rows(nt, neumann(k), links(:, k), n_rows, rows, glob)
         sg(1:n_rows) = signs(rows(1:n_rows), k)
         i = neumann(k)
         if (i > 0) then
            a_k(1:n_rows, 1:n_rows) = shapes%cond_a(:, :, i, c)
         else
            a_k(1:n_rows, 1:n_rows) = shapes%czc(:, :, c)
         end if
         do a = 1, n_rows
            if (glob(a) == free_slot) cycle
            do q = 1, n_rows
               if (glob(q) == free_slot) cycle
               h(glob(q), glob(a)) = h(glob(q), glob(a)) + sg(q)*sg(a)*a_k(q, a)
            end do
         end do
      end do
      pinned = .not. any(links == edge_free)
      if (pinned) then
         h(1, :) = 0.0_dp
         h(:, 1) = 0.0_dp
         h(1, 1) = 1.0_dp
      end if
      call block_factor(h, n_blocks, 3*nt, factor, ok)
      factor%pinned = pinned
      allocate (factor%n_rows(size(classes)), factor%rows(3*nt, size(classes)), factor%glob(3*nt, size(classes)), &
                factor%sg(3*nt, size(classes)))
      factor%rows = 0
      factor%glob = 0
      factor%sg = 0.0_dp
      do k = 1, size(classes)
         call inner_rows(nt, neumann(k), links(:, k), factor%n_rows(k), factor%rows(:, k), factor%glob(:, k))
         n_rows = factor%n_rows(k)
         factor%sg(1:n_rows, k) = signs(factor%rows(1:n_rows, k), k)
      end do
   end subroutine condensed_factor

   !> solve_patch for a patch whose H was factorized beforehand
   !> (condensed_factor, for a patch with the same classes, neumann, links and relative signs):
   !> only the right-hand sides and the triangles' fluxes are computed per patch, for both
   !> membranes at once (each class operator and each number of the factor is read once for
   !> the two, whose values sit side by side: mat_vec). Triangle k is at ratio ratios(k) to its
   !> class (one value on a red-refined level; a bisected mesh mixes sizes, which H does not
   !> see: its blocks C z Cᵀ do not change with the ratio). The flux datum of triangle k is
   !> (σ_0, φ_j)_K = ρ⁻² Φ_i fgrad(:, k, r) with Φ_i =
   !> psi_phi(:, :, neumann(k)) of the class, i.e. σ_0 = fgrad ψ_i for the vertex opposite the
   !> zero-flux edge. A triangle without one takes no datum: in a discretization-flux patch it
   !> is a boundary vertex's triangle whose far edge lies on ∂Ω, so all three of its vertices
   !> do, where u_h is the constant Dirichlet value (g, or 0): its ∇u_h, hence its datum, is
   !> zero up to round-off. Free edges (on ∂Ω) have no multiplier: their trace rows point to
   !> free_slot (inner_rows). With the patch's own trace signs S and the orientation O of each
   !> multiplier (the sign of its first row), the patch's system is O H O; the products S O are
   !> the signature's relative signs (factor%sg), so neither the patch's signs nor O is needed:
   !> b = Σ_K (S O)_K t_K, and θ_K = (S O)_K θ back (±1 factors, exact). The patch's σ on
   !> triangle k is added to sigma(:, triangles(k), :) (the caller's whole field: no copy of the
   !> patch's part).
   pure subroutine solve_condensed_factored(space, shapes, classes, ratios, neumann, fgrad, rhs_div, flux_data, factor, &
                                            triangles, sigma)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      integer, intent(in) :: classes(:), neumann(:)
      real(dp), intent(in) :: ratios(:), fgrad(:, :, :), rhs_div(:, :, :)
      logical, intent(in) :: flux_data
      type(patch_factor_t), intent(in) :: factor
      integer(ip), intent(in) :: triangles(:)
      real(dp), intent(inout) :: sigma(:, :, :)

      integer, parameter :: max_rows = 6, max_flux = 8, max_div = 3
      integer :: nf, nd, nc, k, c, i, a, j, q, n_rows, n_theta, n_data
      integer(ip) :: t
      real(dp) :: b(2, free_slot)
      !> a triangle's data for the condensed operators, both membranes side by side:
      !> [g; ρ⁻¹ fgrad] and [ρ g; θ; fgrad]
      real(dp) :: rho, s, t1(2, max_rows), data_q(2, max_div + 2), data_r(2, max_div + max_rows + 2), f(2, max_flux)

      nf = space%n_flux
      nd = space%n_div
      nc = 3*space%n_trace
      ! without a flux datum the operators' fgrad columns are left out
      n_data = merge(2, 0, flux_data)
      n_theta = factor%n_theta
      b(:, 1:n_theta) = 0.0_dp
      b(:, free_slot) = 0.0_dp
      do k = 1, size(classes)
         c = classes(k)
         rho = ratios(k)
         n_rows = factor%n_rows(k)
         i = neumann(k)
         do q = 1, nd
            data_q(:, q) = rhs_div(q, k, 1:2)
         end do
         if (i > 0) then
            if (flux_data) then
               do q = 1, 2
                  data_q(:, nd + q) = (1/rho)*fgrad(q, k, 1:2)
               end do
            end if
            call mat_vec(n_rows, nd + n_data, shapes%cond_q(:, 1:nd + n_data, i, c), data_q, t1)
         else
            call mat_vec(n_rows, nd, shapes%cy(:, :, c), data_q, t1)
         end if
         do a = 1, n_rows
            j = factor%glob(a, k)
            b(:, j) = b(:, j) + factor%sg(a, k)*t1(:, a)
         end do
      end do
      if (factor%pinned) b(:, 1) = 0.0_dp
      call block_apply(factor, b(:, 1:max_theta))
      b(:, free_slot) = 0.0_dp
      do k = 1, size(classes)
         c = classes(k)
         rho = ratios(k)
         n_rows = factor%n_rows(k)
         i = neumann(k)
         do q = 1, nd
            data_r(:, q) = rho*rhs_div(q, k, 1:2)
         end do
         do a = 1, n_rows
            s = -rho*factor%sg(a, k)
            data_r(:, nd + a) = s*b(:, factor%glob(a, k))
         end do
         if (i > 0) then
            if (flux_data) then
               do q = 1, 2
                  data_r(:, nd + n_rows + q) = fgrad(q, k, 1:2)
               end do
            end if
            call mat_vec(nf, nd + n_rows + n_data, shapes%cond_r(:, 1:nd + n_rows + n_data, i, c), data_r, f)
         else
            call mat_vec(nf, nd + nc, shapes%y_zc(:, :, c), data_r, f)
         end if
         t = triangles(k)
         do q = 1, nf
            sigma(q, t, 1) = sigma(q, t, 1) + f(1, q)
            sigma(q, t, 2) = sigma(q, t, 2) + f(2, q)
         end do
      end do
   end subroutine solve_condensed_factored

   !> The factor of block_solve's elimination (see patch_factor_t), for block_apply.
   pure subroutine block_factor(h, n_blocks, g, f, ok)
      real(dp), intent(in) :: h(:, :)
      integer, intent(in) :: n_blocks, g
      type(patch_factor_t), intent(out) :: f
      logical, intent(out) :: ok

      integer :: nb, ns, ib, r0, i, j, q, n_cpl, max_cpl
      real(dp) :: acc

      nb = n_blocks*g
      ns = size(h, 1) - nb
      f%n_theta = size(h, 1)
      f%n_blocks = n_blocks
      f%g = g
      allocate (f%n_cols(n_blocks))
      max_cpl = 0
      do ib = 1, n_blocks
         r0 = (ib - 1)*g
         f%n_cols(ib) = count([(any(h(r0 + 1:r0 + g, nb + j) /= 0.0_dp), j=1, ns)])
         max_cpl = max(max_cpl, f%n_cols(ib))
      end do
      allocate (f%d(g, g, n_blocks), f%x(g, max_cpl, n_blocks), f%cols(max_cpl, n_blocks), &
                f%s(ns, ns))
      f%s = h(nb + 1:, nb + 1:)
      ok = .true.
      do ib = 1, n_blocks
         r0 = (ib - 1)*g
         f%d(:, :, ib) = h(r0 + 1:r0 + g, r0 + 1:r0 + g)
         call chol_factor(g, f%d(:, :, ib), ok)
         if (.not. ok) return
         n_cpl = 0
         do j = 1, ns
            if (any(h(r0 + 1:r0 + g, nb + j) /= 0.0_dp)) then
               n_cpl = n_cpl + 1
               f%cols(n_cpl, ib) = j
               f%x(:, n_cpl, ib) = h(r0 + 1:r0 + g, nb + j)
            end if
         end do
         call chol_solve(g, f%d(:, :, ib), n_cpl, f%x(:, :, ib))
         call chol_invert(g, f%d(:, :, ib))
         ! S = H_tt − H_tb D⁻¹ H_bt on the touched tail entries
         do j = 1, n_cpl
            do i = 1, n_cpl
               acc = 0.0_dp
               do q = 1, g
                  acc = acc + h(r0 + q, nb + f%cols(i, ib))*f%x(q, j, ib)
               end do
               f%s(f%cols(i, ib), f%cols(j, ib)) = f%s(f%cols(i, ib), f%cols(j, ib)) - acc
            end do
         end do
      end do
      if (ns > 0) then
         call chol_factor(ns, f%s, ok)
         if (ok) call chol_invert(ns, f%s)
      end if
   end subroutine block_factor

   !> b(:, 1:n_theta) = H⁻¹ b for both membranes (b(α, i): membrane α, unknown i) with the
   !> factor of block_factor: each stored number is read once for the two right-hand sides.
   pure subroutine block_apply(f, b)
      type(patch_factor_t), intent(in) :: f
      real(dp), intent(inout) :: b(2, max_theta)

      integer :: nb, ns, ib, r0, i, q, g, nc
      real(dp) :: t(2, max_theta), u(2, max_theta), acc(2)

      g = f%g
      nb = f%n_blocks*g
      ns = f%n_theta - nb
      ! b_t − H_tb D⁻¹ b_b = b_t − xᵀ b_b on the tail unknowns each block touches (each entry of
      ! xᵀ b_b summed over the block's rows in order, as a product with a stored transpose
      ! would), and D⁻¹ b_b kept in place of b_b
      do ib = 1, f%n_blocks
         r0 = (ib - 1)*g
         do i = 1, f%n_cols(ib)
            acc = 0.0_dp
            do q = 1, g
               acc = acc + f%x(q, i, ib)*b(:, r0 + q)
            end do
            b(:, nb + f%cols(i, ib)) = b(:, nb + f%cols(i, ib)) - acc
         end do
         call inverse_apply(g, f%d(:, :, ib), b(:, r0 + 1:r0 + g))
      end do
      if (ns > 0) call inverse_apply(ns, f%s, b(:, nb + 1:nb + ns))
      ! θ_b = D⁻¹ b_b − x θ_t on the tail unknowns each block touches
      do ib = 1, f%n_blocks
         r0 = (ib - 1)*g
         nc = f%n_cols(ib)
         if (nc == 0) cycle
         do i = 1, nc
            t(:, i) = b(:, nb + f%cols(i, ib))
         end do
         call mat_vec(g, nc, f%x(:, 1:nc, ib), t, u)
         b(:, r0 + 1:r0 + g) = b(:, r0 + 1:r0 + g) - u(:, 1:g)
      end do
   end subroutine block_apply

   !> y(:, 1:m) = A x(:, 1:n) for a contiguous m×n matrix A and both membranes side by side
   !> (x(α, j): membrane α): one pass over A, each entry times the pair x(:, j), which the
   !> compiler makes one vector operation. The rows go by eight, four, two, then one, with their
   !> sums in local arrays of fixed size, which stay in registers across the columns (RT1's
   !> products are 8 and 4 rows tall). These products run a few hundred times per patch.
   pure subroutine mat_vec(m, n, a, x, y)
      integer, intent(in) :: m, n
      real(dp), intent(in) :: a(m, n), x(2, n)
      real(dp), intent(out) :: y(2, m)

      integer :: i0, i, j
      real(dp) :: acc(2, 8)

      i0 = 0
      do while (m - i0 >= 8)
         acc = 0.0_dp
         do j = 1, n
            do i = 1, 8
               acc(:, i) = acc(:, i) + a(i0 + i, j)*x(:, j)
            end do
         end do
         y(:, i0 + 1:i0 + 8) = acc
         i0 = i0 + 8
      end do
      if (m - i0 >= 4) then
         acc(:, 1:4) = 0.0_dp
         do j = 1, n
            do i = 1, 4
               acc(:, i) = acc(:, i) + a(i0 + i, j)*x(:, j)
            end do
         end do
         y(:, i0 + 1:i0 + 4) = acc(:, 1:4)
         i0 = i0 + 4
      end if
      if (m - i0 >= 2) then
         acc(:, 1:2) = 0.0_dp
         do j = 1, n
            do i = 1, 2
               acc(:, i) = acc(:, i) + a(i0 + i, j)*x(:, j)
            end do
         end do
         y(:, i0 + 1:i0 + 2) = acc(:, 1:2)
         i0 = i0 + 2
      end if
      if (m > i0) then
         acc(:, 1) = 0.0_dp
         do j = 1, n
            acc(:, 1) = acc(:, 1) + a(m, j)*x(:, j)
         end do
         y(:, m) = acc(:, 1)
      end if
   end subroutine mat_vec

   !> a = (L Lᵀ)⁻¹, whole (both triangles), from the factor L of chol_factor.
   pure subroutine chol_invert(n, a)
      integer, intent(in) :: n
      real(dp), intent(inout) :: a(n, n)

      real(dp) :: e(n, n)
      integer :: i

      e = 0.0_dp
      do i = 1, n
         e(i, i) = 1.0_dp
      end do
      call chol_solve(n, a, n, e)
      a = e
   end subroutine chol_invert

   !> b = A b for both membranes side by side (b(α, j): membrane α) with a contiguous n×n A.
   pure subroutine inverse_apply(n, a, b)
      integer, intent(in) :: n
      real(dp), intent(in) :: a(n, n)
      real(dp), intent(inout) :: b(2, n)

      real(dp) :: y(2, max_theta)

      call mat_vec(n, n, a, b, y)
      b = y(:, 1:n)
   end subroutine inverse_apply

   !> The trace rows of a patch triangle whose edge `neumann` (0: none) carries zero flux: in
   !> the order of the class's condensed operators (edges neumann+1, neumann+2), with their
   !> patch unknowns glob (free_slot for a free edge's rows).
   pure subroutine inner_rows(nt, neumann, links, n_rows, rows, glob)
      integer, intent(in) :: nt, neumann, links(3)
      integer, intent(out) :: n_rows, rows(:), glob(:)

      integer :: m, l, e

      n_rows = 0
      do m = 1, merge(2, 3, neumann > 0)
         e = merge(modulo(neumann + m - 1, 3) + 1, m, neumann > 0)
         do l = 1, nt
            n_rows = n_rows + 1
            rows(n_rows) = (e - 1)*nt + l
            glob(n_rows) = merge((links(e) - 1)*nt + l, free_slot, links(e) > 0)
         end do
      end do
   end subroutine inner_rows
end module twomem_estimate_patch_factor
