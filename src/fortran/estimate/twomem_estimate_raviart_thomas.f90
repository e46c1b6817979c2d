!> Raviart–Thomas spaces RT_p(K), p = 0 or 1, on one triangle, with the divergence space P_p(K)
!> and the normal-trace space P_p(e) of each edge: everything the patch problems of the flux
!> reconstructions need (docs/method.md §3). The basis is monomial in the scaled coordinates
!> ξ = (x − x_K)/h_K (x_K the barycentre, h_K the diameter), not the usual edge-moment basis:
!> the patch solver enforces normal continuity with edge multipliers (hybridization), so it
!> never needs basis functions shared across edges, and a monomial basis makes the coefficients
!> of several patches' contributions on one element simply add. Scaling by h_K keeps the
!> element matrices O(1)·|K| whatever the mesh size.
!>   RT0: (1,0), (0,1), ξ.            RT1: (1,0), (0,1), (ξ1,0), (ξ2,0), (0,ξ1), (0,ξ2), ξ1 ξ, ξ2 ξ.
!>   P0: 1.                           P1: 1, ξ1, ξ2.
!> On an edge, the trace basis is 1 (and t for p = 1), t ∈ [−1, 1] running from the edge's
!> lower-numbered mesh vertex to the higher one, so both neighbours agree on it.
module twomem_estimate_raviart_thomas
   use twomem_base_kinds, only: dp, ip
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   implicit none
   private

   public :: rt_space_t, rt_frame_t, make_frame, frame_of, edge_gauss

   !> 3-point Gauss–Legendre on [−1, 1] (exact to degree 5): traces of RT1 times P1 are cubic.
   real(dp), parameter :: edge_gauss(2, 3) = reshape([-sqrt(0.6_dp), 5.0_dp/9, 0.0_dp, 8.0_dp/9, &
                                                      sqrt(0.6_dp), 5.0_dp/9], [2, 3])

   type :: rt_space_t
      integer :: order = 1
      !> dimensions of RT_p(K), P_p(K) and P_p(e)
      integer :: n_flux = 8, n_div = 3, n_trace = 2
      !> degree-5 rule: RT1·RT1 is degree 4, (r ψ_a, q) degree 3
      type(quadrature_t) :: rule
   contains
      procedure :: init
      procedure :: flux_values
      procedure :: divergence_values
      procedure :: div_test_values
      procedure :: element_matrices
   end type rt_space_t

   !> Where the monomials of one triangle live: its vertices, barycentre, scale (its diameter,
   !> the longest edge, as mesh_t%diameter_of computes it) and area.
   type :: rt_frame_t
      real(dp) :: vertices(2, 3) = 0.0_dp
      real(dp) :: centre(2) = 0.0_dp, scale = 1.0_dp, area = 0.0_dp
   end type rt_frame_t

contains

   subroutine init(self, order)
      class(rt_space_t), intent(out) :: self
      integer, intent(in) :: order

      self%order = order
      if (order == 0) then
         self%n_flux = 3
         self%n_div = 1
         self%n_trace = 1
      else
         self%n_flux = 8
         self%n_div = 3
         self%n_trace = 2
      end if
      self%rule = triangle_rule(5)
   end subroutine init

   pure function make_frame(vertices) result(frame)
      real(dp), intent(in) :: vertices(2, 3)
      type(rt_frame_t) :: frame

      frame%vertices = vertices
      frame%centre = sum(vertices, dim=2)/3
      frame%scale = max(norm2(vertices(:, 2) - vertices(:, 1)), norm2(vertices(:, 3) - vertices(:, 2)), &
                        norm2(vertices(:, 1) - vertices(:, 3)))
      frame%area = 0.5_dp*abs((vertices(1, 2) - vertices(1, 1))*(vertices(2, 3) - vertices(2, 1)) - &
                              (vertices(1, 3) - vertices(1, 1))*(vertices(2, 2) - vertices(2, 1)))
   end function make_frame

   !> make_frame of the triangle with vertices v of the mesh coordinates `vertices` (2, nv),
   !> gathered vertex by vertex: the vector subscript vertices(:, v) costs a heap temporary.
   pure function frame_of(vertices, v) result(frame)
      real(dp), intent(in) :: vertices(:, :)
      integer(ip), intent(in) :: v(3)
      type(rt_frame_t) :: frame

      real(dp) :: p(2, 3)
      integer :: i

      do i = 1, 3
         p(:, i) = vertices(:, v(i))
      end do
      frame = make_frame(p)
   end function frame_of

   !> φ_i(x), (2, n_flux).
   pure function flux_values(self, frame, x) result(phi)
      class(rt_space_t), intent(in) :: self
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: x(2)
      real(dp) :: phi(2, self%n_flux)

      real(dp) :: xi(2)

      xi = (x - frame%centre)/frame%scale
      phi = 0.0_dp
      phi(1, 1) = 1.0_dp
      phi(2, 2) = 1.0_dp
      if (self%order == 0) then
         phi(:, 3) = xi
      else
         phi(1, 3) = xi(1)
         phi(1, 4) = xi(2)
         phi(2, 5) = xi(1)
         phi(2, 6) = xi(2)
         phi(:, 7) = xi(1)*xi
         phi(:, 8) = xi(2)*xi
      end if
   end function flux_values

   !> ∇·φ_i(x), (n_flux).
   pure function divergence_values(self, frame, x) result(div)
      class(rt_space_t), intent(in) :: self
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: x(2)
      real(dp) :: div(self%n_flux)

      real(dp) :: xi(2)

      div = 0.0_dp
      if (self%order == 0) then
         div(3) = 2/frame%scale
      else
         xi = (x - frame%centre)/frame%scale
         div(3) = 1/frame%scale
         div(6) = 1/frame%scale
         div(7) = 3*xi(1)/frame%scale
         div(8) = 3*xi(2)/frame%scale
      end if
   end function divergence_values

   !> q_k(x) of the divergence space P_p(K), (n_div).
   pure function div_test_values(self, frame, x) result(q)
      class(rt_space_t), intent(in) :: self
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: x(2)
      real(dp) :: q(self%n_div)

      q(1) = 1.0_dp
      if (self%order == 1) q(2:3) = (x - frame%centre)/frame%scale
   end function div_test_values

   !> mass(i,j) = (φ_j, φ_i)_K, div(k,i) = (∇·φ_i, q_k)_K and, for the edge opposite local vertex
   !> m, trace(l,i,m) = ⟨φ_i·n_K, μ_l⟩_e with n_K the outward normal and μ_l the trace basis
   !> oriented by `forward(m)` (.true.: t runs from local vertex m+1 to m+2).
   pure subroutine element_matrices(self, frame, forward, mass, div, trace)
      class(rt_space_t), intent(in) :: self
      type(rt_frame_t), intent(in) :: frame
      logical, intent(in) :: forward(3)
      real(dp), intent(out) :: mass(self%n_flux, self%n_flux), div(self%n_div, self%n_flux)
      real(dp), intent(out) :: trace(self%n_trace, self%n_flux, 3)

      real(dp) :: x(2), w, phi(2, self%n_flux), d(self%n_flux), q(self%n_div), p(2), e(2), normal(2), t
      integer :: k, m, g, i

      mass = 0.0_dp
      div = 0.0_dp
      do k = 1, self%rule%n
         x = matmul(frame%vertices, self%rule%bary(:, k))
         w = self%rule%weights(k)*frame%area
         phi = self%flux_values(frame, x)
         d = self%divergence_values(frame, x)
         q = self%div_test_values(frame, x)
         mass = mass + w*matmul(transpose(phi), phi)
         do i = 1, self%n_div
            div(i, :) = div(i, :) + w*q(i)*d
         end do
      end do
      trace = 0.0_dp
      do m = 1, 3
         p = frame%vertices(:, modulo(m, 3) + 1)
         e = frame%vertices(:, modulo(m + 1, 3) + 1) - p
         ! counter-clockwise triangle: the outward normal is the edge direction turned clockwise
         normal = [e(2), -e(1)]/norm2(e)
         do g = 1, 3
            t = edge_gauss(1, g)
            x = p + 0.5_dp*(1 + t)*e
            w = 0.5_dp*edge_gauss(2, g)*norm2(e)
            if (.not. forward(m)) t = -t
            phi = self%flux_values(frame, x)
            trace(1, :, m) = trace(1, :, m) + w*matmul(normal, phi)
            if (self%n_trace == 2) trace(2, :, m) = trace(2, :, m) + w*t*matmul(normal, phi)
         end do
      end do
   end subroutine element_matrices
end module twomem_estimate_raviart_thomas
