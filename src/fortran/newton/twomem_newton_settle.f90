!> The contact set of an interpolated initial guess, settled before Newton starts. Nested
!> iteration interpolates the coarser level's (u1, u2, λ) to the new vertices; next to the free
!> boundary a new vertex lies between a contact and a free neighbour, so both u1 − u2 (of order
!> h² there) and λ (of order one) come out positive, and Newton-min's first linearization puts
!> every such vertex in contact. About half of them are not, and the first Newton steps move the
!> contact set by that layer and then by its echoes (1763, 42, 17, 1 and 0 vertices over five
!> steps at 1.1·10^6 vertices, membranes-min; seven steps for bbbv at 4.5·10^6). Here every
!> vertex where the guess breaks complementarity, and each of its neighbours, takes the solution
!> of its own complementarity problem with its neighbours' values fixed (projected Jacobi,
!> `sweeps` sweeps): a local decision of the side of the free boundary a vertex lies on, at the
!> cost of one row product per marked vertex and sweep. Newton converges to the same discrete
!> solution, from a start whose contact set is nearly right. Jacobi rather than Gauss–Seidel
!> (which we measured to give the same Newton counts) because its result does not depend on
!> the order of the vertices, nor on the partition of a distributed run: the marks and the
!> rows of shared vertices are summed across ranks, like every other product.
module twomem_newton_settle
   use twomem_base_kinds, only: dp, ip
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_vectors, only: fill, threaded_from
   use twomem_linalg_halo, only: halo_t
   implicit none
   private

   public :: settle_contact

   !> one sweep decided as much as six in every case we measured; the second is a margin
   integer, parameter :: sweeps = 2

contains

   !> Settle x = [X1; X2; X3] (interior values of u1, u2, λ on p's unknowns) where it breaks
   !> u1 − u2 ≥ 0, λ ≥ 0, (u1 − u2) λ = 0. `settled` (optional) returns how many of this
   !> rank's unknowns were relaxed. Collective.
   subroutine settle_contact(p, x, settled)
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(inout) :: x(:)
      integer(ip), intent(out), optional :: settled

      real(dp), allocatable :: near(:), rows(:, :)
      integer(ip), allocatable :: list(:)
      integer(ip) :: n, i, k
      integer :: sweep

      n = p%n
      allocate (near(n))
      call fill(near, 0.0_dp)
      ! the broken vertices are a layer along the free boundary: few, so their rows are marked
      ! on one thread
      do i = 1, n
         if (breaks_complementarity(x(i) - x(n + i), x(2*n + i))) then
            near(p%stiffness%col(p%stiffness%row_ptr(i):p%stiffness%row_ptr(i + 1) - 1)) = 1.0_dp
         end if
      end do
      call add_across_ranks(p, near)
      list = pack([(i, i=1, n)], near > 0.0_dp)
      deallocate (near)
      if (present(settled)) settled = size(list, kind=ip)
      allocate (rows(3, size(list)))
      do sweep = 1, sweeps
         !$omp parallel do default(none) shared(p, x, list, rows) private(k) schedule(static) &
         !$omp if(size(list) > threaded_from)
         do k = 1, size(list, kind=ip)
            call row_parts(p, list(k), x, rows(:, k))
         end do
         !$omp end parallel do
         call sum_shared(p, list, rows)
         !$omp parallel do default(none) shared(p, x, list, rows, n) private(k, i) schedule(static) &
         !$omp if(size(list) > threaded_from)
         do k = 1, size(list, kind=ip)
            i = list(k)
            call local_solution(p, i, rows(:, k), x(i), x(n + i), x(2*n + i))
         end do
         !$omp end parallel do
      end do
   end subroutine settle_contact

   pure logical function breaks_complementarity(w, lambda) result(breaks)
      real(dp), intent(in) :: w, lambda

      breaks = (w > 0.0_dp .and. lambda > 0.0_dp) .or. w < 0.0_dp .or. lambda < 0.0_dp
   end function breaks_complementarity

   !> This rank's part of vertex i's row: K_ii and the neighbours' sums Σ_j≠i K_ij u1_j and
   !> Σ_j≠i K_ij u2_j.
   pure subroutine row_parts(p, i, x, parts)
      type(discrete_problem_t), intent(in) :: p
      integer(ip), intent(in) :: i
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: parts(3)

      integer(ip) :: m, j

      parts = 0.0_dp
      do m = p%stiffness%row_ptr(i), p%stiffness%row_ptr(i + 1) - 1
         j = p%stiffness%col(m)
         if (j == i) then
            parts(1) = p%stiffness%val(m)
         else
            parts(2) = parts(2) + p%stiffness%val(m)*x(j)
            parts(3) = parts(3) + p%stiffness%val(m)*x(p%n + j)
         end if
      end do
   end subroutine row_parts

   !> The row parts of shared vertices summed across ranks (nothing to do on one rank).
   !> Collective.
   subroutine sum_shared(p, list, rows)
      type(discrete_problem_t), intent(in) :: p
      integer(ip), intent(in) :: list(:)
      real(dp), intent(inout) :: rows(:, :)

      real(dp), allocatable :: whole(:)
      integer :: c

      if (p%halo%comm%size == 1) return
      allocate (whole(p%n))
      do c = 1, 3
         whole = 0.0_dp
         whole(list) = rows(c, :)
         call add_across_ranks(p, whole)
         rows(c, :) = whole(list)
      end do
   end subroutine sum_shared

   !> v summed over the ranks that share its entries (p's halo, whose buffers a sum writes:
   !> a copy, as p is the caller's and read-only here). Collective.
   subroutine add_across_ranks(p, v)
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(inout) :: v(:)

      type(halo_t) :: halo

      if (p%halo%comm%size == 1) return
      halo = p%halo
      call halo%add(v)
   end subroutine add_across_ranks

   !> Vertex i's complementarity problem with its neighbours fixed, from its row parts (K_ii, and
   !> the neighbours' sums s1, s2): μ1 K_ii u1 − D_i λ = r1, μ2 K_ii u2 + D_i λ = r2 with
   !> r_α = F_α,i − μ_α s_α. Free (λ = 0) if that leaves u1 ≥ u2; in contact otherwise, where
   !> u1 = u2 = (r1 + r2)/((μ1 + μ2) K_ii) and λ = (μ1 r2 − μ2 r1)/((μ1 + μ2) D_i), positive
   !> exactly when the free values cross.
   pure subroutine local_solution(p, i, parts, u1, u2, lambda)
      type(discrete_problem_t), intent(in) :: p
      integer(ip), intent(in) :: i
      real(dp), intent(in) :: parts(3)
      real(dp), intent(out) :: u1, u2, lambda

      real(dp) :: r1, r2, kii, u

      kii = parts(1)
      r1 = p%f(i) - p%mu1*parts(2)
      r2 = p%f(p%n + i) - p%mu2*parts(3)
      if (r1/p%mu1 >= r2/p%mu2) then
         u1 = r1/(p%mu1*kii)
         u2 = r2/(p%mu2*kii)
         lambda = 0.0_dp
      else
         u = (r1 + r2)/((p%mu1 + p%mu2)*kii)
         u1 = u
         u2 = u
         lambda = (p%mu1*r2 - p%mu2*r1)/((p%mu1 + p%mu2)*p%mass(i))
      end if
   end subroutine local_solution
end module twomem_newton_settle
