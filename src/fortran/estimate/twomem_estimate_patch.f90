!> One patch problem of the flux reconstructions: find σ in RT_p on a few triangles with
!> prescribed divergence moments, normal flux continuous inside the patch, zero normal flux on
!> the patch boundary (except on ∂Ω where the patch touches it), minimizing ‖σ − σ_0‖ in the
!> mixed sense (paper eqs. (36) and (1.80) of the thesis). Solved by hybridization: each
!> triangle's own mixed system is eliminated locally with its inverse, precomputed once per mesh
!> (rt_matrices_t), the zero-flux constraints of its patch-boundary edge by a 2×2 Schur
!> complement, leaving a small symmetric positive (semi)definite system for the multipliers of
!> normal continuity on the patch's inner edges. For a vertex patch of RT1 that
!> is 2 unknowns per inner edge (12 for six triangles) instead of a ~40-unknown indefinite
!> system, and for the refined patches of the multilevel algebraic flux 60 instead of ~180.
!> When no edge touches ∂Ω the multipliers are defined up to a constant (the Neumann
!> compatibility of the data makes any choice work): the first one is pinned to zero.
module twomem_estimate_patch
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_dense, only: lu_factor, lu_solve, cholesky_factor, cholesky_solve
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_matrices_t
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

   !> elements(k): the mesh triangle of patch triangle k, whose precomputed operators are in
   !> `matrices`; links(m,k): the edge opposite local vertex m is inner edge links(m,k) > 0, or
   !> edge_free (on ∂Ω, no condition) or edge_neumann (σ·n = 0). For each right-hand side r,
   !> rhs_flux(:,k,r) holds (σ_0, φ_i)_K and rhs_div(:,k,r) the moments (∇·σ, q_k)_K to reach;
   !> sigma(:,k,r) returns the coefficients of σ|_K. ok is .false. if a system is singular.
   pure subroutine solve_patch(space, matrices, elements, links, rhs_flux, rhs_div, sigma, ok)
      type(rt_space_t), intent(in) :: space
      type(rt_matrices_t), intent(in) :: matrices
      integer(ip), intent(in) :: elements(:)
      integer, intent(in) :: links(:, :)
      real(dp), intent(in) :: rhs_flux(:, :, :), rhs_div(:, :, :)
      real(dp), intent(out) :: sigma(:, :, :)
      logical, intent(out) :: ok

      integer :: nt, ne, nr, n_theta, nc, nf
      real(dp) :: h(space%n_trace*max(0, maxval(links)), space%n_trace*max(0, maxval(links)))
      real(dp) :: b(size(h, 1), size(rhs_flux, 3))
      !> flux response to each trace row of each triangle, after its zero-flux edges are enforced
      real(dp) :: response(space%n_flux, 3*space%n_trace, size(elements))
      real(dp) :: c_response(3*space%n_trace, 3*space%n_trace), c_sigma(3*space%n_trace, size(rhs_flux, 3))
      real(dp) :: schur(3*space%n_trace, 3*space%n_trace), rhs(3*space%n_trace, 3*space%n_trace + size(rhs_flux, 3))
      integer :: rows_n(3*space%n_trace), rows_i(3*space%n_trace), global_i(3*space%n_trace), piv(3*space%n_trace)
      integer :: k, m, l, i, j, nn, ni, r

      nt = space%n_trace
      nf = space%n_flux
      nc = 3*nt
      ne = size(elements)
      nr = size(rhs_flux, 3)
      n_theta = size(h, 1)
      h = 0.0_dp
      b = 0.0_dp
      ok = .true.

      do k = 1, ne
         associate (z => matrices%z(:, :, elements(k)), y => matrices%y(:, :, elements(k)), &
                    zc => matrices%zc(:, :, elements(k)), czc => matrices%czc(:, :, elements(k)), &
                    cy => matrices%cy(:, :, elements(k)))
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
            ! the triangle alone: σ = z F + y G, its traces C σ (loops: no array temporaries here,
            ! this is the innermost work of every estimator evaluation)
            do r = 1, nr
               do i = 1, nf
                  sigma(i, k, r) = dot_product(z(i, :), rhs_flux(:, k, r)) + dot_product(y(i, :), rhs_div(:, k, r))
               end do
               do i = 1, nc
                  c_sigma(i, r) = dot_product(zc(:, i), rhs_flux(:, k, r)) + dot_product(cy(i, :), rhs_div(:, k, r))
               end do
            end do
            response(:, :, k) = zc
            c_response = czc
            if (nn > 0) then
               ! zero flux through the patch boundary: a Schur complement on its trace rows
               do j = 1, nn
                  do i = 1, nn
                     schur(i, j) = czc(rows_n(i), rows_n(j))
                  end do
                  rhs(j, 1:nc) = czc(rows_n(j), :)
                  rhs(j, nc + 1:nc + nr) = c_sigma(rows_n(j), :)
               end do
               call lu_factor(schur(1:nn, 1:nn), piv, ok)
               if (.not. ok) return
               call lu_solve(schur(1:nn, 1:nn), piv, rhs(1:nn, 1:nc + nr))
               do j = 1, nn
                  do r = 1, nr
                     sigma(:, k, r) = sigma(:, k, r) - zc(:, rows_n(j))*rhs(j, nc + r)
                     c_sigma(:, r) = c_sigma(:, r) - czc(:, rows_n(j))*rhs(j, nc + r)
                  end do
                  do i = 1, nc
                     response(:, i, k) = response(:, i, k) - zc(:, rows_n(j))*rhs(j, i)
                     c_response(:, i) = c_response(:, i) - czc(:, rows_n(j))*rhs(j, i)
                  end do
               end do
            end if
         end associate
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
      call cholesky_factor(h, ok)
      if (.not. ok) return
      call cholesky_solve(h, b)
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
end module twomem_estimate_patch
