!> The algebraic residual as a function (paper §4.1): from R_α = F_α − (rows α of E X) at the
!> interior vertices, the piecewise P1 function r_α with (r_α, ψ_a)_K = R_α(a)/N_a on every
!> triangle K of the patch of a (N_a triangles) and r_α = 0 at boundary vertices. Summing over
!> the patch gives (r_α, ψ_a) = R_α(a), so the first two block rows of the inexact Newton system
!> read as exact equilibria with source f_α ∓ λ_h − r_α, which the flux reconstructions need.
module twomem_estimate_lifting
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_halo, only: halo_t
   implicit none
   private

   public :: algebraic_residuals, patch_shares, lifting_on_triangle

contains

   !> R_1 = F_1 − μ1 S X1 + D X3 and R_2 = F_2 − μ2 S X2 − D X3 as nodal fields: residual(:, α)
   !> = R_α at the vertices of the unknowns, zero at the others (nv values per column). On a
   !> rank's piece of a distributed problem, `halo` (a copy of p%halo) sums the ranks' parts of
   !> S X_α at shared vertices (F_α and D hold full values already), so every local unknown gets
   !> the full residual. `work` (at least n values) holds S X_α on its way to the vertices: the
   !> unknowns are not numbered in vertex order (twomem_fem_transfer), so it cannot move within
   !> `residual` itself.
   subroutine algebraic_residuals(p, x, residual, work, halo)
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: residual(:, :)
      real(dp), intent(inout) :: work(:)
      type(halo_t), intent(inout), optional :: halo

      integer(ip) :: n, i
      integer :: alpha
      real(dp) :: mu, sign

      n = p%n
      do alpha = 1, 2
         call p%stiffness%matvec(x((alpha - 1)*n + 1:alpha*n), work(1:n))
         if (present(halo)) call halo%add(work(1:n))
         mu = merge(p%mu1, p%mu2, alpha == 1)
         sign = merge(1.0_dp, -1.0_dp, alpha == 1)
         !$omp parallel default(none) shared(p, x, residual, work, n, alpha, mu, sign) private(i)
         !$omp workshare
         residual(:, alpha) = 0.0_dp
         !$omp end workshare
         !$omp do schedule(static)
         do i = 1, n
            residual(p%interior(i), alpha) = p%f((alpha - 1)*n + i) - mu*work(i) + (sign*p%mass(i))*x(2*n + i)
         end do
         !$omp end do
         !$omp end parallel
      end do
   end subroutine algebraic_residuals

   !> In place, residual(a, j) = R(a)/N_a for each column j: the part of R(a) that each of the N_a
   !> triangles of the patch of a carries (zero at boundary vertices, where r vanishes).
   subroutine patch_shares(mesh, residual)
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(inout) :: residual(:, :)

      integer(ip) :: a
      real(dp) :: patch_size

      !$omp parallel do default(none) shared(mesh, residual) private(a, patch_size) schedule(static)
      do a = 1, mesh%nv
         if (mesh%boundary_vertex(a)) then
            residual(a, :) = 0.0_dp
         else
            patch_size = mesh%patch_ptr(a + 1) - mesh%patch_ptr(a)
            residual(a, :) = residual(a, :)/patch_size
         end if
      end do
      !$omp end parallel do
   end subroutine patch_shares

   !> r(:, j) = the values at the three vertices of triangle t of the lifting whose patch shares
   !> (`patch_shares`) are shares(:, j), for each column j.
   pure subroutine lifting_on_triangle(mesh, shares, t, r)
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: shares(:, :)
      integer(ip), intent(in) :: t
      real(dp), intent(out) :: r(:, :)

      integer :: i, n_free, free(3), col
      real(dp) :: rhs(3), det, diagonal, off_diagonal, scale

      n_free = 0
      do i = 1, 3
         if (.not. mesh%boundary_vertex(mesh%triangles(i, t))) then
            n_free = n_free + 1
            free(n_free) = i
         end if
      end do
      ! the P1 mass matrix of t is |t|/12 (1 + δ_ij): solve its free-vertex block
      select case (n_free)
      case (3)
         ! inverse of (|t|/12)(I + 11ᵀ): (12/|t|)(I − 11ᵀ/4)
         scale = 12/mesh%area(t)
         do col = 1, size(r, 2)
            do i = 1, 3
               rhs(i) = shares(mesh%triangles(i, t), col)
            end do
            r(:, col) = scale*(rhs - sum(rhs)/4)
         end do
      case (2)
         diagonal = 2.0_dp*mesh%area(t)/12
         off_diagonal = 1.0_dp*mesh%area(t)/12
         det = diagonal*diagonal - off_diagonal*off_diagonal
         do col = 1, size(r, 2)
            do i = 1, 2
               rhs(i) = shares(mesh%triangles(free(i), t), col)
            end do
            r(:, col) = 0.0_dp
            r(free(1), col) = (diagonal*rhs(1) - off_diagonal*rhs(2))/det
            r(free(2), col) = (diagonal*rhs(2) - off_diagonal*rhs(1))/det
         end do
      case (1)
         diagonal = 2.0_dp*mesh%area(t)/12
         do col = 1, size(r, 2)
            r(:, col) = 0.0_dp
            r(free(1), col) = shares(mesh%triangles(free(1), t), col)/diagonal
         end do
      case default
         r = 0.0_dp
      end select
   end subroutine lifting_on_triangle
end module twomem_estimate_lifting
