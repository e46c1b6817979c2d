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
!> compatibility of the data makes any choice work): the first one is pinned to zero.
module twomem_estimate_patch
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_dense, only: lu_factor, lu_solve, cholesky_factor, cholesky_solve
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t
   implicit none
   private

   public :: solve_patch, inner_edge, edge_free, edge_neumann

   !> edge kinds in `links`: a positive value numbers an inner edge of the patch
   integer, parameter :: edge_free = 0, edge_neumann = -1

contains

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

      integer :: nt, ne, nr, n_theta, nc, nf
      real(dp) :: h(space%n_trace*max(0, maxval(links)), space%n_trace*max(0, maxval(links)))
      real(dp) :: b(size(h, 1), size(rhs_flux, 3))
      !> flux response to each trace row of each triangle, after its zero-flux edges are enforced
      real(dp) :: response(space%n_flux, 3*space%n_trace, size(classes))
      real(dp) :: c_response(3*space%n_trace, 3*space%n_trace), c_sigma(3*space%n_trace, size(rhs_flux, 3))
      real(dp) :: schur(3*space%n_trace, 3*space%n_trace), rhs(3*space%n_trace, 3*space%n_trace + size(rhs_flux, 3))
      integer :: rows_n(3*space%n_trace), rows_i(3*space%n_trace), global_i(3*space%n_trace), piv(3*space%n_trace)
      integer :: k, m, l, i, j, nn, ni, r, c
      real(dp) :: rho, rho2, s(3*space%n_trace), zf(space%n_flux), czf(3*space%n_trace)
      real(dp) :: zc_k(space%n_flux, 3*space%n_trace), czc_k(3*space%n_trace, 3*space%n_trace)

      nt = space%n_trace
      nf = space%n_flux
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
         nn = 0
         ni = 0
         do m = 1, 3
            do l = 1, nt
               if (links(m, k) == edge_neumann) then
                  nn = nn + 1
                  rows_n(nn) = (m - 1)*nt + l
               else if (links(m, k) > 0) then
                  ni = ni + 1
                  rows_i(ni) = (m - 1)*nt + l
                  global_i(ni) = (links(m, k) - 1)*nt + l
               end if
            end do
         end do
         ! the triangle alone: σ = z F + y G and its traces C σ, with the class operators
         ! z → ρ² z, y → ρ y, z Cᵀ → ρ z Cᵀ S, C z Cᵀ → S C z Cᵀ S, C y → S C y (S = signs)
         do r = 1, nr
            do i = 1, nf
               sigma(i, k, r) = rho*dot_product(shapes%y(i, :, c), rhs_div(:, k, r))
            end do
            do i = 1, nc
               c_sigma(i, r) = s(i)*dot_product(shapes%cy(i, :, c), rhs_div(:, k, r))
            end do
            if (flux_data) then
               do i = 1, nf
                  zf(i) = dot_product(shapes%z(i, :, c), rhs_flux(:, k, r))
               end do
               sigma(:, k, r) = sigma(:, k, r) + rho2*zf
               do i = 1, nc
                  czf(i) = dot_product(shapes%zc(:, i, c), rhs_flux(:, k, r))
               end do
               c_sigma(:, r) = c_sigma(:, r) + rho*s*czf
            end if
         end do
         do i = 1, nc
            zc_k(:, i) = (rho*s(i))*shapes%zc(:, i, c)
            czc_k(:, i) = (s*s(i))*shapes%czc(:, i, c)
         end do
         response(:, :, k) = zc_k
         c_response = czc_k
         if (nn > 0) then
            ! zero flux through the patch boundary: a Schur complement on its trace rows
            do j = 1, nn
               do i = 1, nn
                  schur(i, j) = czc_k(rows_n(i), rows_n(j))
               end do
               rhs(j, 1:nc) = czc_k(rows_n(j), :)
               rhs(j, nc + 1:nc + nr) = c_sigma(rows_n(j), :)
            end do
            call lu_factor(schur(1:nn, 1:nn), piv, ok)
            if (.not. ok) return
            call lu_solve(schur(1:nn, 1:nn), piv, rhs(1:nn, 1:nc + nr))
            do j = 1, nn
               do r = 1, nr
                  sigma(:, k, r) = sigma(:, k, r) - zc_k(:, rows_n(j))*rhs(j, nc + r)
                  c_sigma(:, r) = c_sigma(:, r) - czc_k(:, rows_n(j))*rhs(j, nc + r)
               end do
               do i = 1, nc
                  response(:, i, k) = response(:, i, k) - zc_k(:, rows_n(j))*rhs(j, i)
                  c_response(:, i) = c_response(:, i) - czc_k(:, rows_n(j))*rhs(j, i)
               end do
            end do
         end if
         ! σ_K = particular − Σ response θ; continuity Σ_K C_K σ_K = 0 on inner edges gives H θ = b
         do i = 1, ni
            do j = 1, ni
               h(global_i(i), global_i(j)) = h(global_i(i), global_i(j)) + c_response(rows_i(i), rows_i(j))
            end do
            b(global_i(i), :) = b(global_i(i), :) + c_sigma(rows_i(i), :)
         end do
      end do
      if (n_theta == 0) return

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
         call cholesky_factor(h, ok)
         if (ok) call cholesky_solve(h, b)
      end if
      if (.not. ok) return
      do k = 1, ne
         do m = 1, 3
            if (links(m, k) <= 0) cycle
            do l = 1, nt
               i = (links(m, k) - 1)*nt + l
               do r = 1, nr
                  sigma(:, k, r) = sigma(:, k, r) - b(i, r)*response(:, (m - 1)*nt + l, k)
               end do
            end do
         end do
      end do
   end subroutine solve_patch

   !> H θ = b for symmetric positive definite H whose first n_blocks diagonal blocks of size g
   !> couple only with the unknowns after them (the tail): eliminate each block (Cholesky), the
   !> tail's Schur complement by Cholesky, then back-substitute. b returns θ; h is destroyed.
   pure subroutine block_solve(h, b, n_blocks, g, ok)
      real(dp), intent(inout) :: h(:, :), b(:, :)
      integer, intent(in) :: n_blocks, g
      logical, intent(out) :: ok

      integer :: nb, ns, ib, r0, i, j, n_cpl, cpl(size(h, 1))
      real(dp) :: d(g, g), x(g, size(h, 1), n_blocks), y(g, size(b, 2), n_blocks)
      integer :: cols(size(h, 1), n_blocks), n_cols(n_blocks)

      nb = n_blocks*g
      ns = size(h, 1) - nb
      ok = .true.
      do ib = 1, n_blocks
         r0 = (ib - 1)*g
         d = h(r0 + 1:r0 + g, r0 + 1:r0 + g)
         call cholesky_factor(d, ok)
         if (.not. ok) return
         ! the tail unknowns this block touches
         n_cpl = 0
         do j = nb + 1, nb + ns
            if (any(h(r0 + 1:r0 + g, j) /= 0.0_dp)) then
               n_cpl = n_cpl + 1
               cpl(n_cpl) = j
            end if
         end do
         x(:, 1:n_cpl, ib) = h(r0 + 1:r0 + g, cpl(1:n_cpl))
         y(:, :, ib) = b(r0 + 1:r0 + g, :)
         call cholesky_solve(d, x(:, 1:n_cpl, ib))
         call cholesky_solve(d, y(:, :, ib))
         ! S = H_tt − H_tb D⁻¹ H_bt and b_t − H_tb D⁻¹ b_b on the touched tail entries
         do j = 1, n_cpl
            do i = 1, n_cpl
               h(cpl(i), cpl(j)) = h(cpl(i), cpl(j)) - dot_product(h(r0 + 1:r0 + g, cpl(i)), x(:, j, ib))
            end do
         end do
         do i = 1, n_cpl
            b(cpl(i), :) = b(cpl(i), :) - matmul(h(r0 + 1:r0 + g, cpl(i)), y(:, :, ib))
         end do
         cols(1:n_cpl, ib) = cpl(1:n_cpl)
         n_cols(ib) = n_cpl
      end do
      if (ns > 0) then
         call cholesky_factor(h(nb + 1:, nb + 1:), ok)
         if (.not. ok) return
         call cholesky_solve(h(nb + 1:, nb + 1:), b(nb + 1:, :))
      end if
      do ib = 1, n_blocks
         r0 = (ib - 1)*g
         b(r0 + 1:r0 + g, :) = y(:, :, ib) - matmul(x(:, 1:n_cols(ib), ib), b(cols(1:n_cols(ib), ib), :))
      end do
   end subroutine block_solve
end module twomem_estimate_patch
