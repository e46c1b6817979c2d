!> Kernels of the element pass of the estimators (twomem_estimate_estimators): the data
!> oscillation of the loads, fixed on a mesh and computed once; the three quadratic forms of a
!> triangle's RT mass matrix that give the flux norms η_F, η_disc and η_alg in one pass; and the
!> change of a coarser level's RT_p field into a finer triangle's scaled basis.
module twomem_estimate_element_terms
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_linalg_dense, only: lu_factor, lu_solve
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, frame_of
   implicit none
   private

   public :: data_oscillation, quadratic_forms, add_in_child_basis

contains

   !> (h_K C) μ_α^{−1/2} ‖f_α − Π_1 f_α‖_K with the load's degree-5 rule, C = `constant`.
   subroutine data_oscillation(space, mesh, data, mu, osc, constant)
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp), intent(in) :: mu(2)
      real(dp), allocatable, intent(out) :: osc(:, :)
      !> the Poincaré constant over h_K: 1/π (the paper) or 1/j_{1,1} (any triangle)
      real(dp), intent(in) :: constant

      type(rt_frame_t) :: frame
      real(dp) :: x(2), w, q(3), gram(3, 3), b(3, 2), projection(3, 2), f(2), ff(2)
      integer :: k, i, alpha, piv(3)
      logical :: ok
      integer(ip) :: t

      allocate (osc(2, mesh%nt))
      !$omp parallel do default(none) shared(space, mesh, data, mu, osc, constant) &
      !$omp private(t, frame, x, w, q, gram, b, projection, f, ff, k, i, alpha, piv, ok) schedule(static)
      do t = 1, mesh%nt
         frame = frame_of(mesh%vertices, mesh%triangles(:, t))
         gram = 0.0_dp
         b = 0.0_dp
         ff = 0.0_dp
         do k = 1, space%rule%n
            x = matmul(frame%vertices, space%rule%bary(:, k))
            w = space%rule%weights(k)*frame%area
            q = space%div_test_values(frame, x)
            f = [data%load(1, x), data%load(2, x)]
            do i = 1, 3
               gram(:, i) = gram(:, i) + w*q*q(i)
            end do
            do alpha = 1, 2
               b(:, alpha) = b(:, alpha) + w*f(alpha)*q
            end do
            ff = ff + w*f**2
         end do
         ! ‖f − Π f‖² = ‖f‖² − (Π f, f) = ‖f‖² − bᵀ G⁻¹ b
         projection = b
         call lu_factor(gram, piv, ok)
         call lu_solve(gram, piv, projection)
         do alpha = 1, 2
            ! (the frame's scale is the triangle's diameter, mesh_t%diameter_of)
            osc(alpha, t) = frame%scale*constant/sqrt(mu(alpha))* &
                            sqrt(max(0.0_dp, ff(alpha) - dot_product(b(:, alpha), projection(:, alpha))))
         end do
      end do
      !$omp end parallel do
   end subroutine data_oscillation

   !> q = (aᵀ M a, bᵀ M b, (a + b)ᵀ M (a + b)) for a contiguous n×n matrix M, in one pass over M:
   !> the third reuses the columns' products with a and b, (a + b)ᵀ(M a + M b).
   pure subroutine quadratic_forms(n, m, a, b, q)
      integer, intent(in) :: n
      real(dp), intent(in) :: m(n, n), a(n), b(n)
      real(dp), intent(out) :: q(3)

      integer :: i, j
      real(dp) :: row_a, row_b

      q = 0.0_dp
      if (n == 8) then
         ! RT1: a loop of constant length, unrolled
         do j = 1, 8
            row_a = 0.0_dp
            row_b = 0.0_dp
            do i = 1, 8
               row_a = row_a + m(i, j)*a(i)
               row_b = row_b + m(i, j)*b(i)
            end do
            q(1) = q(1) + a(j)*row_a
            q(2) = q(2) + b(j)*row_b
            q(3) = q(3) + (a(j) + b(j))*(row_a + row_b)
         end do
         return
      end if
      do j = 1, n
         row_a = 0.0_dp
         row_b = 0.0_dp
         do i = 1, n
            row_a = row_a + m(i, j)*a(i)
            row_b = row_b + m(i, j)*b(i)
         end do
         q(1) = q(1) + a(j)*row_a
         q(2) = q(2) + b(j)*row_b
         q(3) = q(3) + (a(j) + b(j))*(row_a + row_b)
      end do
   end subroutine quadratic_forms

   !> f + the coefficients in the basis of a child triangle of the RT_p field with coefficients c
   !> in the basis of its ancestor: with ξ_parent = d + κ ξ_child (d the child's barycentre in the
   !> parent's scaled coordinates, κ the ratio of the scales), each monomial field expands
   !> exactly, e.g. ξ1 ξ = d1 d + κ(2 d1 ξ1, d2 ξ1 + d1 ξ2) + κ² ξ1 ξ. Added in place, as the
   !> caller sums the levels: no temporary, and the same sums as adding a converted copy.
   pure subroutine add_in_child_basis(order, d, kappa, c, f)
      integer, intent(in) :: order
      real(dp), intent(in) :: d(2), kappa, c(:)
      real(dp), intent(inout) :: f(:)

      if (order == 0) then
         f(1) = f(1) + (c(1) + d(1)*c(3))
         f(2) = f(2) + (c(2) + d(2)*c(3))
         f(3) = f(3) + kappa*c(3)
      else
         f(1) = f(1) + (c(1) + d(1)*c(3) + d(2)*c(4) + d(1)**2*c(7) + d(1)*d(2)*c(8))
         f(2) = f(2) + (c(2) + d(1)*c(5) + d(2)*c(6) + d(1)*d(2)*c(7) + d(2)**2*c(8))
         f(3) = f(3) + kappa*(c(3) + 2*d(1)*c(7) + d(2)*c(8))
         f(4) = f(4) + kappa*(c(4) + d(1)*c(8))
         f(5) = f(5) + kappa*(c(5) + d(2)*c(7))
         f(6) = f(6) + kappa*(c(6) + d(1)*c(7) + 2*d(2)*c(8))
         f(7) = f(7) + kappa**2*c(7)
         f(8) = f(8) + kappa**2*c(8)
      end if
   end subroutine add_in_child_basis
end module twomem_estimate_element_terms
