!> The operators of one triangle's mixed problem computed from its own vertices: what the patch
!> problems of a mesh whose triangles are not copies of a few shape classes need (a Gmsh mesh
!> solved as given, a hierarchy refined too little for its classes to repeat), without any
!> stored per-triangle or per-class data. The space and basis are those of
!> twomem_estimate_raviart_thomas (scaled monomials of ξ = (x − x_K)/h_K); every integral is of
!> a polynomial in ξ and is formed from closed forms: the monomial moments ∫_K ξ^α (|α| ≤ 4) by
!> the degree-5 rule (exact), the traces from the edges' end points (the normal component of
!> every basis field is linear along an edge, since ξ·n is constant there), the barycentric
!> products by their exact formula. The mixed matrix [M Bᵀ; B 0] is inverted by blocks: M⁻¹ by
!> the blocks of M's own structure (rt1_operators), then the divergence's 3×3 (1×1) Schur
!> complement S = B M⁻¹ Bᵀ:
!>   y = M⁻¹ Bᵀ S⁻¹,  z = M⁻¹ − y B M⁻¹,
!> the blocks of the inverse that twomem_estimate_shapes stores per class. The edges are
!> oriented by the triangle's local order (t from local vertex m+1 to m+2), as the classes'.
!> A flux datum σ_0 = ψ_i c (c constant: −μ∇u_h) enters through z Φ_iᵀ c with Φ_i the moments
!> of ψ_i against the basis: for RT1, ψ_i c lies in RT1 itself, so M⁻¹Φ_iᵀ is its coefficient
!> matrix E_i and z Φ_iᵀ = E_i − y (B E_i), B E_i = (∫ q_k) ∇ψ_iᵀ, without a product with M⁻¹.
!> A container holds the operators of a block of triangles (one per slot), as the patch loop
!> of one thread fills and reads them (twomem_estimate_generic_patch).
module twomem_estimate_triangle_ops
   use twomem_base_kinds, only: dp
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, make_frame
   implicit none
   private

   public :: triangle_ops_t, rt_mass_matrix

   !> the monomials ξ1^a ξ2^b, a + b ≤ 4, in the order of `moments` (index mono(a, b))
   integer, parameter :: n_moments = 15

   type :: triangle_ops_t
      !> slots allocated (triangles whose operators fit)
      integer :: capacity = 0
      integer :: nf = 0, nd = 0, nc = 0
      !> per slot s, for the triangle computed there (local edge orientation):
      !> y(:, :, s) and zc(:, :, s) = z Cᵀ, czc(:, :, s) = C z Cᵀ, trace(:, :, s) = C (the trace
      !> rows of the three edges, n_trace each, edge 1 first), z_phi(:, :, i, s) = z Φ_iᵀ for the
      !> hat function ψ_i of local vertex i (the flux datum's operator, (n_flux, 2))
      real(dp), allocatable :: y(:, :, :), zc(:, :, :), czc(:, :, :), trace(:, :, :), z_phi(:, :, :, :)
      !> patch data: psi_q(k, i, s) = ∫ ψ_i q_k, bary_psi_q(k, j, i, s) = ∫ λ_j ψ_i q_k,
      !> q_int(k, s) = ∫ q_k
      real(dp), allocatable :: psi_q(:, :, :), bary_psi_q(:, :, :, :), q_int(:, :)
   contains
      procedure :: reserve
      procedure :: compute
   end type triangle_ops_t

contains

   !> Room for n triangles' operators of `space` (kept when there is already as much).
   pure subroutine reserve(self, space, n)
      class(triangle_ops_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      integer, intent(in) :: n

      integer :: nf, nd, nc

      if (self%capacity >= n .and. self%nf == space%n_flux) return
      nf = space%n_flux
      nd = space%n_div
      nc = 3*space%n_trace
      if (allocated(self%y)) deallocate (self%y, self%zc, self%czc, self%trace, self%z_phi, self%psi_q, &
                                         self%bary_psi_q, self%q_int)
      allocate (self%y(nf, nd, n), self%zc(nf, nc, n), self%czc(nc, nc, n), self%trace(nc, nf, n), &
                self%z_phi(nf, 2, 3, n), self%psi_q(nd, 3, n), self%bary_psi_q(nd, 3, 3, n), self%q_int(nd, n))
      self%capacity = n
      self%nf = nf
      self%nd = nd
      self%nc = nc
   end subroutine reserve

   !> The operators of the triangle with vertices v (counter-clockwise) into slot s. ok is .false.
   !> if its mixed matrix is singular (a degenerate triangle).
   pure subroutine compute(self, space, s, v, ok)
      class(triangle_ops_t), intent(inout) :: self
      type(rt_space_t), intent(in) :: space
      integer, intent(in) :: s
      real(dp), intent(in) :: v(2, 3)
      logical, intent(out) :: ok

      type(rt_frame_t) :: frame
      real(dp) :: m(n_moments), p(2, 3), g(2, 3)
      integer :: i, j, k

      frame = make_frame(v)
      do i = 1, 3
         p(:, i) = (v(:, i) - frame%centre)/frame%scale
      end do
      m = moments(space, frame, p)
      ! ∇_ξ λ_i = h ∇λ_i: the opposite edge rotated by −90°, over twice the area in ξ
      do i = 1, 3
         j = modulo(i, 3) + 1
         k = modulo(i + 1, 3) + 1
         g(1, i) = (p(2, j) - p(2, k))/(2*frame%area/frame%scale**2)
         g(2, i) = (p(1, k) - p(1, j))/(2*frame%area/frame%scale**2)
      end do
      call data_integrals(space, frame, p, m, self%psi_q(:, :, s), self%bary_psi_q(:, :, :, s), self%q_int(:, s))
      if (space%order == 1) then
         call rt1_operators(self, s, v, p, m, g, frame, ok)
      else
         call rt0_operators(self, s, v, p, m, frame, ok)
      end if
   end subroutine compute

   !> RT1: M⁻¹ by blocks. In the basis order (φ1, φ3, φ4 | φ2, φ5, φ6 | φ7, φ8) the mass matrix
   !> is [G 0 A; 0 G E; Aᵀ Eᵀ D] with G the P1 Gram matrix of (1, ξ1, ξ2), so with a = G⁻¹A,
   !> e = G⁻¹E and T = D − Aᵀa − Eᵀe (2×2): M⁻¹ = [G⁻¹ + a T⁻¹aᵀ, a T⁻¹eᵀ, −a T⁻¹; ...; T⁻¹],
   !> three divisions in all. Bᵀ has nonzeros in the rows of φ3, φ6, φ7, φ8 only.
   pure subroutine rt1_operators(self, s, v, p, m, g, frame, ok)
      type(triangle_ops_t), intent(inout) :: self
      integer, intent(in) :: s
      real(dp), intent(in) :: v(2, 3), p(2, 3), m(n_moments), g(2, 3)
      type(rt_frame_t), intent(in) :: frame
      logical, intent(out) :: ok

      integer, parameter :: xs(3) = [1, 3, 4], ys(3) = [2, 5, 6], ds(2) = [7, 8]
      real(dp) :: gram(3, 3), gi(3, 3), am(3, 2), em(3, 2), d(2, 2), a(3, 2), e(3, 2), t(2, 2), ti(2, 2)
      real(dp) :: w(8, 8), bt(4, 3), x(8, 3), sc(3, 3), si(3, 3), z(8, 8), c(6, 8), ta(3, 2), te(3, 2), h, acc
      real(dp) :: be(3, 2)
      integer :: i, j, k, q

      h = frame%scale
      ! (element by element: an array constructor through reshape is a library call per use)
      gram(1, 1) = m(mono(0, 0))
      gram(2, 1) = m(mono(1, 0))
      gram(3, 1) = m(mono(0, 1))
      gram(2, 2) = m(mono(2, 0))
      gram(3, 2) = m(mono(1, 1))
      gram(3, 3) = m(mono(0, 2))
      gram(1, 2) = gram(2, 1)
      gram(1, 3) = gram(3, 1)
      gram(2, 3) = gram(3, 2)
      am(1, 1) = m(mono(2, 0))
      am(2, 1) = m(mono(3, 0))
      am(3, 1) = m(mono(2, 1))
      am(1, 2) = m(mono(1, 1))
      am(2, 2) = m(mono(2, 1))
      am(3, 2) = m(mono(1, 2))
      em(1, 1) = m(mono(1, 1))
      em(2, 1) = m(mono(2, 1))
      em(3, 1) = m(mono(1, 2))
      em(1, 2) = m(mono(0, 2))
      em(2, 2) = m(mono(1, 2))
      em(3, 2) = m(mono(0, 3))
      d(1, 1) = m(mono(4, 0)) + m(mono(2, 2))
      d(2, 1) = m(mono(3, 1)) + m(mono(1, 3))
      d(1, 2) = d(2, 1)
      d(2, 2) = m(mono(2, 2)) + m(mono(0, 4))
      call inverse3(gram, gi, ok)
      if (.not. ok) return
      do j = 1, 2
         do i = 1, 3
            a(i, j) = gi(i, 1)*am(1, j) + gi(i, 2)*am(2, j) + gi(i, 3)*am(3, j)
            e(i, j) = gi(i, 1)*em(1, j) + gi(i, 2)*em(2, j) + gi(i, 3)*em(3, j)
         end do
      end do
      do j = 1, 2
         do i = 1, 2
            t(i, j) = d(i, j) - (am(1, i)*a(1, j) + am(2, i)*a(2, j) + am(3, i)*a(3, j)) &
                      - (em(1, i)*e(1, j) + em(2, i)*e(2, j) + em(3, i)*e(3, j))
         end do
      end do
      call inverse2(t, ti, ok)
      if (.not. ok) return
      do j = 1, 2
         do i = 1, 3
            ta(i, j) = a(i, 1)*ti(1, j) + a(i, 2)*ti(2, j)
            te(i, j) = e(i, 1)*ti(1, j) + e(i, 2)*ti(2, j)
         end do
      end do
      do j = 1, 3
         do i = 1, 3
            w(xs(i), xs(j)) = gi(i, j) + (ta(i, 1)*a(j, 1) + ta(i, 2)*a(j, 2))
            w(ys(i), ys(j)) = gi(i, j) + (te(i, 1)*e(j, 1) + te(i, 2)*e(j, 2))
            w(xs(i), ys(j)) = ta(i, 1)*e(j, 1) + ta(i, 2)*e(j, 2)
            w(ys(j), xs(i)) = w(xs(i), ys(j))
         end do
         do i = 1, 2
            w(xs(j), ds(i)) = -ta(j, i)
            w(ds(i), xs(j)) = -ta(j, i)
            w(ys(j), ds(i)) = -te(j, i)
            w(ds(i), ys(j)) = -te(j, i)
         end do
      end do
      w(7:8, 7:8) = ti
      ! Bᵀ on the rows of φ3, φ6, φ7, φ8 (divergence_from_moments)
      bt(1, 1) = m(mono(0, 0))/h
      bt(1, 2) = m(mono(1, 0))/h
      bt(1, 3) = m(mono(0, 1))/h
      bt(2, :) = bt(1, :)
      bt(3, 1) = 3*m(mono(1, 0))/h
      bt(3, 2) = 3*m(mono(2, 0))/h
      bt(3, 3) = 3*m(mono(1, 1))/h
      bt(4, 1) = 3*m(mono(0, 1))/h
      bt(4, 2) = 3*m(mono(1, 1))/h
      bt(4, 3) = 3*m(mono(0, 2))/h
      ! X = M⁻¹ Bᵀ, S = B X, y = X S⁻¹, z = M⁻¹ − y Xᵀ
      do k = 1, 3
         do i = 1, 8
            x(i, k) = w(i, 3)*bt(1, k) + w(i, 6)*bt(2, k) + w(i, 7)*bt(3, k) + w(i, 8)*bt(4, k)
         end do
      end do
      do k = 1, 3
         do j = 1, 3
            sc(j, k) = bt(1, j)*x(3, k) + bt(2, j)*x(6, k) + bt(3, j)*x(7, k) + bt(4, j)*x(8, k)
         end do
      end do
      call inverse3(sc, si, ok)
      if (.not. ok) return
      associate (y => self%y(:, :, s))
         do k = 1, 3
            do i = 1, 8
               y(i, k) = x(i, 1)*si(1, k) + x(i, 2)*si(2, k) + x(i, 3)*si(3, k)
            end do
         end do
         do j = 1, 8
            do i = 1, 8
               z(i, j) = w(i, j) - (y(i, 1)*x(j, 1) + y(i, 2)*x(j, 2) + y(i, 3)*x(j, 3))
            end do
         end do
         call trace_rows(1, v, p, c)
         self%trace(:, :, s) = c
         associate (zc => self%zc(:, :, s), czc => self%czc(:, :, s))
            do j = 1, 6
               do i = 1, 8
                  acc = 0.0_dp
                  do k = 1, 8
                     acc = acc + z(i, k)*c(j, k)
                  end do
                  zc(i, j) = acc
               end do
            end do
            do j = 1, 6
               do i = 1, j
                  acc = 0.0_dp
                  do k = 1, 8
                     acc = acc + c(i, k)*zc(k, j)
                  end do
                  czc(i, j) = acc
                  czc(j, i) = acc
               end do
            end do
         end associate
         ! z Φ_iᵀ: ψ_i c = (1/3 + g_i·ξ) c lies in RT1 (coefficients E_i), B E_i = (∫ q_k) ∇ψ_iᵀ
         do i = 1, 3
            do q = 1, 3
               be(q, :) = self%q_int(q, s)*g(:, i)/h
            end do
            do j = 1, 2
               do k = 1, 8
                  self%z_phi(k, j, i, s) = -(y(k, 1)*be(1, j) + y(k, 2)*be(2, j) + y(k, 3)*be(3, j))
               end do
            end do
            self%z_phi(1, 1, i, s) = self%z_phi(1, 1, i, s) + 1.0_dp/3
            self%z_phi(2, 2, i, s) = self%z_phi(2, 2, i, s) + 1.0_dp/3
            self%z_phi(3, 1, i, s) = self%z_phi(3, 1, i, s) + g(1, i)
            self%z_phi(4, 1, i, s) = self%z_phi(4, 1, i, s) + g(2, i)
            self%z_phi(5, 2, i, s) = self%z_phi(5, 2, i, s) + g(1, i)
            self%z_phi(6, 2, i, s) = self%z_phi(6, 2, i, s) + g(2, i)
         end do
      end associate
   end subroutine rt1_operators

   !> RT0: the 3×3 mass matrix and 1×3 divergence inverted directly.
   pure subroutine rt0_operators(self, s, v, p, m, frame, ok)
      type(triangle_ops_t), intent(inout) :: self
      integer, intent(in) :: s
      real(dp), intent(in) :: v(2, 3), p(2, 3), m(n_moments)
      type(rt_frame_t), intent(in) :: frame
      logical, intent(out) :: ok

      real(dp) :: mass(3, 3), w(3, 3), div(1, 3), x(3), sc, z(3, 3), c(3, 3), e(3, 2)
      integer :: i, j

      call mass_from_moments(0, m, mass)
      call divergence_from_moments(0, m, frame%scale, div)
      call inverse3(mass, w, ok)
      if (.not. ok) return
      x = matmul(w, div(1, :))
      sc = dot_product(div(1, :), x)
      ok = sc > 0.0_dp
      if (.not. ok) return
      self%y(:, 1, s) = x/sc
      do j = 1, 3
         do i = 1, 3
            z(i, j) = w(i, j) - self%y(i, 1, s)*x(j)
         end do
      end do
      call trace_rows(0, v, p, c)
      self%trace(:, :, s) = c
      self%zc(:, :, s) = matmul(z, transpose(c))
      self%czc(:, :, s) = matmul(c, self%zc(:, :, s))
      ! RT0 does not hold ψ_i c: z times Φ_iᵀ, Φ_i(:, j) = ∫ ψ_i φ_j
      do i = 1, 3
         e(1, :) = [frame%area/3, 0.0_dp]
         e(2, :) = [0.0_dp, frame%area/3]
         e(3, :) = frame%area/12*p(:, i)
         self%z_phi(:, :, i, s) = matmul(z, e)
      end do
   end subroutine rt0_operators

   !> inv = a⁻¹ for a 3×3 matrix by cofactors (one division); ok is .false. if a is singular.
   pure subroutine inverse3(a, inv, ok)
      real(dp), intent(in) :: a(3, 3)
      real(dp), intent(out) :: inv(3, 3)
      logical, intent(out) :: ok

      real(dp) :: det, r

      inv(1, 1) = a(2, 2)*a(3, 3) - a(2, 3)*a(3, 2)
      inv(1, 2) = a(1, 3)*a(3, 2) - a(1, 2)*a(3, 3)
      inv(1, 3) = a(1, 2)*a(2, 3) - a(1, 3)*a(2, 2)
      inv(2, 1) = a(2, 3)*a(3, 1) - a(2, 1)*a(3, 3)
      inv(2, 2) = a(1, 1)*a(3, 3) - a(1, 3)*a(3, 1)
      inv(2, 3) = a(1, 3)*a(2, 1) - a(1, 1)*a(2, 3)
      inv(3, 1) = a(2, 1)*a(3, 2) - a(2, 2)*a(3, 1)
      inv(3, 2) = a(1, 2)*a(3, 1) - a(1, 1)*a(3, 2)
      inv(3, 3) = a(1, 1)*a(2, 2) - a(1, 2)*a(2, 1)
      det = a(1, 1)*inv(1, 1) + a(1, 2)*inv(2, 1) + a(1, 3)*inv(3, 1)
      ok = det /= 0.0_dp
      if (.not. ok) return
      r = 1/det
      inv = r*inv
   end subroutine inverse3

   !> inv = a⁻¹ for a 2×2 matrix; ok is .false. if a is singular.
   pure subroutine inverse2(a, inv, ok)
      real(dp), intent(in) :: a(2, 2)
      real(dp), intent(out) :: inv(2, 2)
      logical, intent(out) :: ok

      real(dp) :: det, r

      det = a(1, 1)*a(2, 2) - a(1, 2)*a(2, 1)
      ok = det /= 0.0_dp
      if (.not. ok) return
      r = 1/det
      inv(1, 1) = a(2, 2)*r
      inv(2, 1) = -a(2, 1)*r
      inv(1, 2) = -a(1, 2)*r
      inv(2, 2) = a(1, 1)*r
   end subroutine inverse2

   !> ∫_K ξ1^a ξ2^b for a + b ≤ 4 (mono(a, b) orders them), by the degree-5 rule: exact.
   pure function moments(space, frame, p) result(m)
      type(rt_space_t), intent(in) :: space
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: p(2, 3)
      real(dp) :: m(n_moments)

      real(dp) :: xi(2), w, pw(0:4, 2)
      integer :: q, a, b

      m = 0.0_dp
      do q = 1, space%rule%n
         xi = p(:, 1)*space%rule%bary(1, q) + p(:, 2)*space%rule%bary(2, q) + p(:, 3)*space%rule%bary(3, q)
         w = space%rule%weights(q)*frame%area
         pw(0, :) = 1.0_dp
         do a = 1, 4
            pw(a, :) = pw(a - 1, :)*xi
         end do
         do a = 0, 4
            do b = 0, 4 - a
               m(mono(a, b)) = m(mono(a, b)) + w*pw(a, 1)*pw(b, 2)
            end do
         end do
      end do
   end function moments

   !> The position of ξ1^a ξ2^b in `moments` (by total degree, then decreasing a).
   pure integer function mono(a, b)
      integer, intent(in) :: a, b

      integer :: n

      n = a + b
      mono = n*(n + 1)/2 + b + 1
   end function mono

   !> The mass matrix (φ_j, φ_i)_K of the monomial basis from the moments.
   pure subroutine mass_from_moments(order, m, mass)
      integer, intent(in) :: order
      real(dp), intent(in) :: m(n_moments)
      real(dp), intent(out) :: mass(:, :)

      integer :: i, j

      mass = 0.0_dp
      if (order == 0) then
         mass(1, 1) = m(mono(0, 0))
         mass(2, 2) = m(mono(0, 0))
         mass(1, 3) = m(mono(1, 0))
         mass(2, 3) = m(mono(0, 1))
         mass(3, 3) = m(mono(2, 0)) + m(mono(0, 2))
      else
         mass(1, 1) = m(mono(0, 0))
         mass(1, 3) = m(mono(1, 0))
         mass(1, 4) = m(mono(0, 1))
         mass(1, 7) = m(mono(2, 0))
         mass(1, 8) = m(mono(1, 1))
         mass(2, 2) = m(mono(0, 0))
         mass(2, 5) = m(mono(1, 0))
         mass(2, 6) = m(mono(0, 1))
         mass(2, 7) = m(mono(1, 1))
         mass(2, 8) = m(mono(0, 2))
         mass(3, 3) = m(mono(2, 0))
         mass(3, 4) = m(mono(1, 1))
         mass(3, 7) = m(mono(3, 0))
         mass(3, 8) = m(mono(2, 1))
         mass(4, 4) = m(mono(0, 2))
         mass(4, 7) = m(mono(2, 1))
         mass(4, 8) = m(mono(1, 2))
         mass(5, 5) = m(mono(2, 0))
         mass(5, 6) = m(mono(1, 1))
         mass(5, 7) = m(mono(2, 1))
         mass(5, 8) = m(mono(1, 2))
         mass(6, 6) = m(mono(0, 2))
         mass(6, 7) = m(mono(1, 2))
         mass(6, 8) = m(mono(0, 3))
         mass(7, 7) = m(mono(4, 0)) + m(mono(2, 2))
         mass(7, 8) = m(mono(3, 1)) + m(mono(1, 3))
         mass(8, 8) = m(mono(2, 2)) + m(mono(0, 4))
      end if
      do j = 1, size(mass, 2)
         do i = j + 1, size(mass, 1)
            mass(i, j) = mass(j, i)
         end do
      end do
   end subroutine mass_from_moments

   !> div(k, i) = (∇·φ_i, q_k)_K: ∇·φ_i is (1/h) times 1 (RT1: φ3, φ6), 2 (RT0: φ3) or 3ξ_a
   !> (RT1: φ7, φ8).
   pure subroutine divergence_from_moments(order, m, h, div)
      integer, intent(in) :: order
      real(dp), intent(in) :: m(n_moments), h
      real(dp), intent(out) :: div(:, :)

      div = 0.0_dp
      if (order == 0) then
         div(1, 3) = 2*m(mono(0, 0))/h
      else
         ! q = 1, ξ1, ξ2
         div(1, 3) = m(mono(0, 0))/h
         div(1, 6) = m(mono(0, 0))/h
         div(1, 7) = 3*m(mono(1, 0))/h
         div(1, 8) = 3*m(mono(0, 1))/h
         div(2, 3) = m(mono(1, 0))/h
         div(2, 6) = m(mono(1, 0))/h
         div(2, 7) = 3*m(mono(2, 0))/h
         div(2, 8) = 3*m(mono(1, 1))/h
         div(3, 3) = m(mono(0, 1))/h
         div(3, 6) = m(mono(0, 1))/h
         div(3, 7) = 3*m(mono(1, 1))/h
         div(3, 8) = 3*m(mono(0, 2))/h
      end if
   end subroutine divergence_from_moments

   !> The trace rows ⟨φ_i·n, μ_l⟩_e of the three edges (edge m opposite local vertex m, from
   !> vertex m+1 to m+2, μ_1 = 1, μ_2 = t ∈ [−1, 1]): φ_i·n = α + β·ξ along the edge (ξ·n = δ
   !> is constant there), so the moments are |e| (α + β·ξ_mid) and |e| β·d/6, d the edge in ξ.
   pure subroutine trace_rows(order, v, p, c_rows)
      integer, intent(in) :: order
      real(dp), intent(in) :: v(2, 3), p(2, 3)
      real(dp), intent(out) :: c_rows(:, :)

      real(dp) :: e(2), length, n(2), mid(2), d(2), delta
      integer :: mm, a, b, r

      c_rows = 0.0_dp
      do mm = 1, 3
         a = modulo(mm, 3) + 1
         b = modulo(mm + 1, 3) + 1
         e = v(:, b) - v(:, a)
         length = norm2(e)
         ! counter-clockwise: the outward normal is the edge direction turned clockwise
         n = [e(2), -e(1)]/length
         mid = 0.5_dp*(p(:, a) + p(:, b))
         d = p(:, b) - p(:, a)
         delta = dot_product(mid, n)
         if (order == 0) then
            c_rows(mm, 1) = length*n(1)
            c_rows(mm, 2) = length*n(2)
            c_rows(mm, 3) = length*delta
         else
            r = 2*(mm - 1) + 1
            c_rows(r, 1) = length*n(1)
            c_rows(r, 2) = length*n(2)
            c_rows(r, 3) = length*n(1)*mid(1)
            c_rows(r, 4) = length*n(1)*mid(2)
            c_rows(r, 5) = length*n(2)*mid(1)
            c_rows(r, 6) = length*n(2)*mid(2)
            c_rows(r, 7) = length*delta*mid(1)
            c_rows(r, 8) = length*delta*mid(2)
            c_rows(r + 1, 3) = length*n(1)*d(1)/6
            c_rows(r + 1, 4) = length*n(1)*d(2)/6
            c_rows(r + 1, 5) = length*n(2)*d(1)/6
            c_rows(r + 1, 6) = length*n(2)*d(2)/6
            c_rows(r + 1, 7) = length*delta*d(1)/6
            c_rows(r + 1, 8) = length*delta*d(2)/6
         end if
      end do
   end subroutine trace_rows

   !> ∫ ψ_i q_k, ∫ λ_j ψ_i q_k and ∫ q_k from ∫ λ_i λ_j λ_l = 2|K| α!/(|α| + 2)! and ξ = Σ λ_l p_l
   !> (Σ p_l = 0: the barycentre is the origin of ξ).
   pure subroutine data_integrals(space, frame, p, m, psi_q, bary_psi_q, q_int)
      type(rt_space_t), intent(in) :: space
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: p(2, 3), m(n_moments)
      real(dp), intent(out) :: psi_q(:, :), bary_psi_q(:, :, :), q_int(:)

      real(dp) :: area, t3
      integer :: i, j, l, a

      area = frame%area
      q_int(1) = m(mono(0, 0))
      psi_q(1, :) = area/3
      do i = 1, 3
         do j = 1, 3
            bary_psi_q(1, j, i) = merge(area/6, area/12, i == j)
         end do
      end do
      if (space%order == 0) return
      q_int(2) = m(mono(1, 0))
      q_int(3) = m(mono(0, 1))
      do i = 1, 3
         do a = 1, 2
            ! ∫ λ_i ξ_a = Σ_l p_la ∫ λ_i λ_l
            psi_q(1 + a, i) = area/12*(p(a, i) + sum(p(a, :)))
            do j = 1, 3
               t3 = 0.0_dp
               do l = 1, 3
                  t3 = t3 + p(a, l)*triple(i, j, l)
               end do
               bary_psi_q(1 + a, j, i) = area*t3
            end do
         end do
      end do

   contains

      !> ∫ λ_i λ_j λ_l / |K|: 1/10, 1/30 or 1/60 as one, two or three indices differ
      pure real(dp) function triple(i1, i2, i3)
         integer, intent(in) :: i1, i2, i3

         if (i1 == i2 .and. i2 == i3) then
            triple = 1.0_dp/10
         else if (i1 == i2 .or. i2 == i3 .or. i1 == i3) then
            triple = 1.0_dp/30
         else
            triple = 1.0_dp/60
         end if
      end function triple
   end subroutine data_integrals

   !> The mass matrix (φ_j, φ_i)_K of the triangle with vertices v, the element estimators'
   !> quadratic form where no shape class holds it.
   pure subroutine rt_mass_matrix(space, v, mass)
      type(rt_space_t), intent(in) :: space
      real(dp), intent(in) :: v(2, 3)
      real(dp), intent(out) :: mass(:, :)

      type(rt_frame_t) :: frame
      real(dp) :: p(2, 3)
      integer :: i

      frame = make_frame(v)
      do i = 1, 3
         p(:, i) = (v(:, i) - frame%centre)/frame%scale
      end do
      call mass_from_moments(space%order, moments(space, frame, p), mass)
   end subroutine rt_mass_matrix
end module twomem_estimate_triangle_ops
