!> One patch problem of the flux reconstructions: find σ in RT_p on a few triangles with
!> prescribed divergence moments, normal flux continuous inside the patch, zero normal flux on
!> the patch boundary (except on ∂Ω where the patch touches it), minimizing ‖σ − σ_0‖ in the
!> mixed sense (paper eqs. (36) and (1.80) of the thesis). Solved by hybridization: each
!> triangle's own mixed system is eliminated locally with the inverse of its shape class
!> (twomem_estimate_shapes), scaled to the triangle and signed to its edge orientations, the
!> zero-flux constraints of its patch-boundary edge by a small Schur complement, leaving a
!> symmetric positive (semi)definite system for the multipliers of normal continuity on the
!> patch's inner edges: 2 unknowns per inner edge for RT1 (12 for a vertex patch of six
!> triangles). The refined patches of the multilevel algebraic flux have 60: there the caller
!> numbers the three inner edges of each coarse triangle's middle child first, so that these
!> unknowns form independent diagonal blocks (they couple only through the halves of the coarse
!> edges at the patch vertex), and the blocks are eliminated first; what remains is a
!> 24-unknown system for a patch of six coarse triangles, about a tenth of the dense work.
!> When no edge touches ∂Ω the multipliers are defined up to a constant (the Neumann
!> compatibility of the data makes any choice work): the first one is pinned to zero. This
!> module is the general path, each patch assembled and factorized on its own, and what the
!> factored path (twomem_estimate_patch_factor, a factor shared by every patch of a signature)
!> builds on: the edge kinds and the small Cholesky kernels.
module twomem_estimate_patch
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_dense, only: lu_factor, lu_solve
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t
   implicit none
   private

   public :: solve_patch, link_edge, on_opposite_edge, edge_free, edge_neumann, chol_factor, chol_solve

   !> edge kinds in `links`: a positive value numbers an inner edge of the patch
   integer, parameter :: edge_free = 0, edge_neumann = -1

contains

   !> Whether edge m of a patch triangle lies on the edge opposite the patch vertex, which is local
   !> vertex `corner` of the patch triangle (refined: of its coarse parent, the triangle being the
   !> parent's child c, 4 the middle one). By refine_red's numbering alone, without reading the
   !> mesh: edge m of every triangle is opposite its vertex m, and corner child c has as its edge
   !> m /= c the half at corner c of the coarse edge opposite corner m.
   pure logical function on_opposite_edge(refined, corner, c, m)
      logical, intent(in) :: refined
      integer, intent(in) :: corner, c, m

      if (refined) then
         on_opposite_edge = c /= 4 .and. c /= corner .and. m == corner
      else
         on_opposite_edge = m == corner
      end if
   end function on_opposite_edge

   !> i: the patch's number of mesh edge e, numbering edges in order of first appearance; inner
   !> holds the edges numbered so far (n_inner of them).
   pure subroutine inner_edge(inner, n_inner, e, i)
      integer(ip), intent(inout) :: inner(:)
      integer, intent(inout) :: n_inner
      integer(ip), intent(in) :: e
      integer, intent(out) :: i

      i = findloc(inner(1:n_inner), e, dim=1)
      if (i == 0) then
         n_inner = n_inner + 1
         inner(n_inner) = e
         i = n_inner
      end if
   end subroutine inner_edge

   !> links(m, k) of solve_patch for edge e of a triangle of vertex a's patch: on ∂Ω free, unless
   !> it is the edge opposite a (`opposite`: on the patch boundary) of an interior vertex's
   !> patch, where it carries zero flux like every opposite edge inside Ω; any other edge an
   !> inner multiplier (inner_edge). The general path and the signatures' keys
   !> (twomem_estimate_patch_classes) both link by this rule, so that a patch's key describes
   !> the system the general path would solve.
   pure subroutine link_edge(on_boundary, opposite, a_on_boundary, e, inner, n_inner, link)
      logical, intent(in) :: on_boundary, opposite, a_on_boundary
      integer(ip), intent(in) :: e
      integer(ip), intent(inout) :: inner(:)
      integer, intent(inout) :: n_inner
      integer, intent(out) :: link

      if (on_boundary) then
         link = merge(edge_neumann, edge_free, opposite .and. .not. a_on_boundary)
      else if (opposite) then
         link = edge_neumann
      else
         call inner_edge(inner, n_inner, e, link)
      end if
   end subroutine link_edge

   !> Patch triangle k is of class classes(k) at ratio ratios(k) (twomem_estimate_shapes), and
   !> signs(:, k) = ±1 turns its class trace rows into the patch's (the mesh's edge
   !> orientation); links(m,k): the edge opposite local vertex m is inner edge links(m,k) > 0,
   !> or edge_free (on ∂Ω, no condition) or edge_neumann (σ·n = 0). For each right-hand side r,
   !> rhs_flux(:,k,r) holds (σ_0, φ_i)_K (zero when flux_data is .false., which skips it) and
   !> rhs_div(:,k,r) the moments (∇·σ, q_k)_K to reach; sigma(:,k,r) returns the coefficients of
   !> σ|_K. The first n_blocks blocks of 3 n_trace multipliers must couple only with the
   !> multipliers after them. ok is .false. if a system is singular.
   pure subroutine solve_patch(space, shapes, classes, ratios, signs, links, rhs_flux, rhs_div, flux_data, n_blocks, &
                               sigma, ok)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      integer, intent(in) :: classes(:)
      real(dp), intent(in) :: ratios(:), signs(:, :)
      integer, intent(in) :: links(:, :)
      real(dp), intent(in) :: rhs_flux(:, :, :), rhs_div(:, :, :)
      logical, intent(in) :: flux_data
      integer, intent(in) :: n_blocks
      real(dp), intent(out) :: sigma(:, :, :)
      logical, intent(out) :: ok

      integer :: nt, ne, nr, n_theta, nc, nf, nd
      real(dp) :: h(space%n_trace*max(0, maxval(links)), space%n_trace*max(0, maxval(links)))
      real(dp) :: b(size(h, 1), size(rhs_flux, 3))
      !> the traces C σ of each triangle's particular solution (no edge multipliers)
      real(dp) :: c_sigma(3*space%n_trace, size(rhs_flux, 3), size(classes))
      real(dp) :: czc(3*space%n_trace, 3*space%n_trace), schur(3*space%n_trace, 3*space%n_trace)
      real(dp) :: rhs(3*space%n_trace, 3*space%n_trace + size(rhs_flux, 3)), mu(3*space%n_trace, size(rhs_flux, 3))
      integer :: rows_n(3*space%n_trace), rows_i(3*space%n_trace), global_i(3*space%n_trace), piv(3*space%n_trace)
      integer :: k, i, j, nn, ni, r, c, q
      real(dp) :: rho, rho2, s(3*space%n_trace), acc

      nt = space%n_trace
      nf = space%n_flux
      nd = space%n_div
      nc = 3*nt
      ne = size(classes)
      nr = size(rhs_flux, 3)
      n_theta = size(h, 1)
      h = 0.0_dp
      b = 0.0_dp
      ok = .true.

      do k = 1, ne
         c = classes(k)
         rho = ratios(k)
         rho2 = rho*rho
         s = signs(:, k)
         call edge_rows(links(:, k), nt, nn, rows_n, ni, rows_i, global_i)
         ! the triangle alone: σ = z F + y G and its traces C σ, with the class operators
         ! z → ρ² z, y → ρ y, z Cᵀ → ρ z Cᵀ S, C z Cᵀ → S C z Cᵀ S, C y → S C y (S = signs)
         do r = 1, nr
            do i = 1, nf
               acc = 0.0_dp
               do q = 1, nd
                  acc = acc + shapes%y(i, q, c)*rhs_div(q, k, r)
               end do
               sigma(i, k, r) = rho*acc
            end do
            do i = 1, nc
               acc = 0.0_dp
               do q = 1, nd
                  acc = acc + shapes%cy(i, q, c)*rhs_div(q, k, r)
               end do
               c_sigma(i, r, k) = s(i)*acc
            end do
            if (flux_data) then
               do i = 1, nf
                  acc = 0.0_dp
                  do q = 1, nf
                     acc = acc + shapes%z(i, q, c)*rhs_flux(q, k, r)
                  end do
                  sigma(i, k, r) = sigma(i, k, r) + rho2*acc
               end do
               do i = 1, nc
                  acc = 0.0_dp
                  do q = 1, nf
                     acc = acc + shapes%zc(q, i, c)*rhs_flux(q, k, r)
                  end do
                  c_sigma(i, r, k) = c_sigma(i, r, k) + rho*s(i)*acc
               end do
            end if
         end do
         do j = 1, nc
            do i = 1, nc
               czc(i, j) = s(i)*s(j)*shapes%czc(i, j, c)
            end do
         end do
         if (nn > 0) then
            ! zero flux through the patch boundary: eliminate its trace rows by a Schur complement
            ! on the inner rows (schur⁻¹ [czc(n, inner) | C σ(n)])
            call neumann_factor(czc, nn, rows_n, schur, piv, ok)
            if (.not. ok) return
            do j = 1, ni
               rhs(1:nn, j) = czc(rows_n(1:nn), rows_i(j))
            end do
            rhs(1:nn, ni + 1:ni + nr) = c_sigma(rows_n(1:nn), :, k)
            call lu_solve(schur(1:nn, 1:nn), piv, rhs(1:nn, 1:ni + nr))
            do j = 1, ni
               do i = 1, ni
                  h(global_i(i), global_i(j)) = h(global_i(i), global_i(j)) + czc(rows_i(i), rows_i(j)) &
                                                - dot_product(czc(rows_i(i), rows_n(1:nn)), rhs(1:nn, j))
               end do
            end do
            do r = 1, nr
               do i = 1, ni
                  b(global_i(i), r) = b(global_i(i), r) + c_sigma(rows_i(i), r, k) &
                                      - dot_product(czc(rows_i(i), rows_n(1:nn)), rhs(1:nn, ni + r))
               end do
            end do
         else
            do j = 1, ni
               do i = 1, ni
                  h(global_i(i), global_i(j)) = h(global_i(i), global_i(j)) + czc(rows_i(i), rows_i(j))
               end do
            end do
            do r = 1, nr
               do i = 1, ni
                  b(global_i(i), r) = b(global_i(i), r) + c_sigma(rows_i(i), r, k)
               end do
            end do
         end if
      end do
      if (n_theta == 0 .and. all(links /= edge_neumann)) return

      if (n_theta > 0) then
         if (.not. any(links == edge_free)) then
            ! only zero-flux boundary: θ is defined up to a constant, pin the first multiplier
            h(1, :) = 0.0_dp
            h(:, 1) = 0.0_dp
            h(1, 1) = 1.0_dp
            b(1, :) = 0.0_dp
         end if
         if (n_blocks > 0) then
            call block_solve(h, b, n_blocks, nc, ok)
         else
            call chol_factor(n_theta, h, ok)
            if (ok) call chol_solve(n_theta, h, nr, b)
         end if
         if (.not. ok) return
      end if
      ! σ_K = particular − ρ z Cᵀ S μ with μ the multipliers of all trace rows of K: θ on inner
      ! edges, the solved Neumann multipliers on patch-boundary edges, zero on free edges
      do k = 1, ne
         c = classes(k)
         rho = ratios(k)
         s = signs(:, k)
         call edge_rows(links(:, k), nt, nn, rows_n, ni, rows_i, global_i)
         mu = 0.0_dp
         do i = 1, ni
            mu(rows_i(i), :) = b(global_i(i), :)
         end do
         if (nn > 0) then
            do j = 1, nc
               do i = 1, nc
                  czc(i, j) = s(i)*s(j)*shapes%czc(i, j, c)
               end do
            end do
            call neumann_factor(czc, nn, rows_n, schur, piv, ok)
            do r = 1, nr
               do i = 1, nn
                  rhs(i, r) = c_sigma(rows_n(i), r, k) - dot_product(czc(rows_n(i), rows_i(1:ni)), mu(rows_i(1:ni), r))
               end do
            end do
            call lu_solve(schur(1:nn, 1:nn), piv, rhs(1:nn, 1:nr))
            do i = 1, nn
               mu(rows_n(i), :) = rhs(i, 1:nr)
            end do
         end if
         do r = 1, nr
            do j = 1, nc
               if (mu(j, r) == 0.0_dp) cycle
               sigma(:, k, r) = sigma(:, k, r) - (rho*s(j)*mu(j, r))*shapes%zc(:, j, c)
            end do
         end do
      end do
   end subroutine solve_patch

   !> In place, lower triangle of a contiguous n×n matrix: a = L Lᵀ; ok is .false. if a is not
   !> positive definite.
   pure subroutine chol_factor(n, a, ok)
      integer, intent(in) :: n
      real(dp), intent(inout) :: a(n, n)
      logical, intent(out) :: ok

      integer :: i, j, k
      real(dp) :: d

      ok = .true.
      do j = 1, n
         do k = 1, j - 1
            do i = j, n
               a(i, j) = a(i, j) - a(i, k)*a(j, k)
            end do
         end do
         if (.not. a(j, j) > 0.0_dp) then
            ok = .false.
            return
         end if
         d = 1/sqrt(a(j, j))
         do i = j, n
            a(i, j) = a(i, j)*d
         end do
      end do
   end subroutine chol_factor

   !> b = (L Lᵀ)⁻¹ b for the m columns of b, with the factor of chol_factor.
   pure subroutine chol_solve(n, a, m, b)
      integer, intent(in) :: n, m
      real(dp), intent(in) :: a(n, n)
      real(dp), intent(inout) :: b(:, :)

      integer :: i, j, k
      real(dp) :: x

      do j = 1, m
         do k = 1, n
            x = b(k, j)/a(k, k)
            b(k, j) = x
            do i = k + 1, n
               b(i, j) = b(i, j) - a(i, k)*x
            end do
         end do
         do k = n, 1, -1
            x = b(k, j)
            do i = k + 1, n
               x = x - a(i, k)*b(i, j)
            end do
            b(k, j) = x/a(k, k)
         end do
      end do
   end subroutine chol_solve

   !> The trace rows of one patch triangle: nn on zero-flux edges, ni on inner edges with their
   !> patch unknowns global_i.
   pure subroutine edge_rows(links, nt, nn, rows_n, ni, rows_i, global_i)
      integer, intent(in) :: links(3), nt
      integer, intent(out) :: nn, rows_n(:), ni, rows_i(:), global_i(:)

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
               global_i(ni) = (links(m) - 1)*nt + l
            end if
         end do
      end do
   end subroutine edge_rows

   !> LU factors of czc restricted to the zero-flux rows.
   pure subroutine neumann_factor(czc, nn, rows_n, schur, piv, ok)
      real(dp), intent(in) :: czc(:, :)
      integer, intent(in) :: nn, rows_n(:)
      real(dp), intent(out) :: schur(:, :)
      integer, intent(out) :: piv(:)
      logical, intent(out) :: ok

      integer :: i, j

      do j = 1, nn
         do i = 1, nn
            schur(i, j) = czc(rows_n(i), rows_n(j))
         end do
      end do
      call lu_factor(schur(1:nn, 1:nn), piv, ok)
   end subroutine neumann_factor

   !> H θ = b for symmetric positive definite H whose first n_blocks diagonal blocks of size g
   !> couple only with the unknowns after them (the tail): eliminate each block (Cholesky), the
   !> tail's Schur complement by Cholesky, then back-substitute. b returns θ.
   pure subroutine block_solve(h, b, n_blocks, g, ok)
      real(dp), intent(in) :: h(:, :)
      real(dp), intent(inout) :: b(:, :)
      integer, intent(in) :: n_blocks, g
      logical, intent(out) :: ok

      integer :: nb, ns, nr, ib, r0, i, j, q, r, n_cpl
      real(dp) :: d(g, g), x(g, size(h, 1) - n_blocks*g, n_blocks), y(g, size(b, 2), n_blocks)
      real(dp) :: s(size(h, 1) - n_blocks*g, size(h, 1) - n_blocks*g), bt(size(h, 1) - n_blocks*g, size(b, 2))
      real(dp) :: acc, hc(g, size(h, 1) - n_blocks*g)
      integer :: cols(size(h, 1) - n_blocks*g, n_blocks), n_cols(n_blocks)

      nb = n_blocks*g
      ns = size(h, 1) - nb
      nr = size(b, 2)
      s = h(nb + 1:, nb + 1:)
      bt = b(nb + 1:, :)
      ok = .true.
      do ib = 1, n_blocks
         r0 = (ib - 1)*g
         d = h(r0 + 1:r0 + g, r0 + 1:r0 + g)
         call chol_factor(g, d, ok)
         if (.not. ok) return
         ! the tail unknowns this block touches
         n_cpl = 0
         do j = 1, ns
            if (any(h(r0 + 1:r0 + g, nb + j) /= 0.0_dp)) then
               n_cpl = n_cpl + 1
               cols(n_cpl, ib) = j
               hc(:, n_cpl) = h(r0 + 1:r0 + g, nb + j)
            end if
         end do
         n_cols(ib) = n_cpl
         x(:, 1:n_cpl, ib) = hc(:, 1:n_cpl)
         y(:, :, ib) = b(r0 + 1:r0 + g, :)
         call chol_solve(g, d, n_cpl, x(:, :, ib))
         call chol_solve(g, d, nr, y(:, :, ib))
         ! S = H_tt − H_tb D⁻¹ H_bt and b_t − H_tb D⁻¹ b_b on the touched tail entries
         do j = 1, n_cpl
            do i = 1, n_cpl
               acc = 0.0_dp
               do q = 1, g
                  acc = acc + hc(q, i)*x(q, j, ib)
               end do
               s(cols(i, ib), cols(j, ib)) = s(cols(i, ib), cols(j, ib)) - acc
            end do
         end do
         do r = 1, nr
            do i = 1, n_cpl
               acc = 0.0_dp
               do q = 1, g
                  acc = acc + hc(q, i)*y(q, r, ib)
               end do
               bt(cols(i, ib), r) = bt(cols(i, ib), r) - acc
            end do
         end do
      end do
      if (ns > 0) then
         call chol_factor(ns, s, ok)
         if (.not. ok) return
         call chol_solve(ns, s, nr, bt)
      end if
      b(nb + 1:, :) = bt
      do ib = 1, n_blocks
         r0 = (ib - 1)*g
         do r = 1, nr
            b(r0 + 1:r0 + g, r) = y(:, r, ib)
            do i = 1, n_cols(ib)
               b(r0 + 1:r0 + g, r) = b(r0 + 1:r0 + g, r) - x(:, i, ib)*bt(cols(i, ib), r)
            end do
         end do
      end do
   end subroutine block_solve
end module twomem_estimate_patch
