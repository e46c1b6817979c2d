!> The parts of the estimators that depend on the iterate alone, without any flux: per
!> triangle the contact term η_C,K = 2(λ⁺, u1 − u2)_K and the nonconformity terms
!> η_nonc,1,K = |||s_h − u_h|||_K (s_h the nodewise projection onto u1 ≥ u2) and
!> η_nonc,2,K = C‖λ⁻‖_K, with ‖λ⁺‖²_K for η_nonc,3, the parts of λ_h integrated exactly (each
!> triangle clipped at λ_h = 0). The element pass of twomem_estimate_estimators uses them per
!> triangle; `iterate_sums` adds them up over a mesh straight from a Newton iterate, which
!> gives η_lin at about a fiftieth of the cost of an evaluation (the adaptive method's choice
!> of its evaluations, twomem_newton_inner).
module twomem_estimate_iterate_parts
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_raviart_thomas, only: rt_frame_t, frame_of
   implicit none
   private

   public :: iterate_parts, iterate_sums, nonconformity

contains

   !> The parts of a triangle that depend on the iterate alone, no flux: η_C,K = 2(λ⁺, u1 − u2)_K,
   !> η_nonc,1,K = |||s_h − u_h|||_K, η_nonc,2,K = C‖λ⁻‖_K and ‖λ⁺‖²_K, from its frame, the
   !> gradients of its barycentric functions (hat), u_α (uv(:, α)) and λ_h (lam) at its vertices
   !> and ∇u_α on it (grad_u(:, α)).
   pure subroutine iterate_parts(frame, hat, c_omega, mu, uv, lam, grad_u, contact_k, nonc1_k, nonc2_k, pos_ll)
      type(rt_frame_t), intent(in) :: frame
      real(dp), intent(in) :: hat(2, 3), c_omega, mu(2), uv(3, 2), lam(3), grad_u(2, 2)
      real(dp), intent(out) :: contact_k, nonc1_k, nonc2_k, pos_ll

      real(dp) :: pos_lw, neg_lw, neg_ll, grad_s(2, 2)
      !> s_h at K's vertices: the nodewise projection onto u1 ≥ u2 (the mean where u1 < u2)
      real(dp) :: s(3, 2)
      integer :: k, alpha

      ! most triangles lie where λ_h ≥ 0 or λ_h ≤ 0 throughout: the other part is then
      ! exactly zero (the clipped polygon has l = 0 at all its points), without clipping
      if (all(lam <= 0.0_dp)) then
         pos_lw = 0.0_dp
         pos_ll = 0.0_dp
      else
         call sign_split(frame%vertices, lam, uv(:, 1) - uv(:, 2), pos_lw, pos_ll)
      end if
      if (all(lam >= 0.0_dp)) then
         neg_lw = 0.0_dp
         neg_ll = 0.0_dp
      else
         call sign_split(frame%vertices, -lam, uv(:, 1) - uv(:, 2), neg_lw, neg_ll)
      end if
      contact_k = 2*pos_lw
      nonc2_k = c_omega*sqrt(neg_ll)
      s = uv
      do k = 1, 3
         if (uv(k, 1) < uv(k, 2)) then
            s(k, 1) = 0.5_dp*(uv(k, 1) + uv(k, 2))
            s(k, 2) = s(k, 1)
         end if
      end do
      do alpha = 1, 2
         grad_s(:, alpha) = matmul(hat, s(:, alpha)) - grad_u(:, alpha)
      end do
      nonc1_k = sqrt(frame%area*(mu(1)*sum(grad_s(:, 1)**2) + mu(2)*sum(grad_s(:, 2)**2)))
   end subroutine iterate_parts


   !> This rank's Σ η_nonc,1,K², Σ η_nonc,2,K² and ‖λ⁺‖² over its own triangles for the Newton
   !> iterate x = [X1; X2; X3] of problem p (boundary values g, 0, 0), c_omega = C. By blocks of
   !> triangles in a fixed order, like the element pass: the sums do not depend on the threads.
   function iterate_sums(mesh, p, x, c_omega, mu) result(sums)
      type(mesh_t), intent(in) :: mesh
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:), c_omega, mu(2)
      real(dp) :: sums(3)

      integer(ip), parameter :: block = 1024
      real(dp), allocatable :: partial(:, :)
      type(rt_frame_t) :: frame
      real(dp) :: uv(3, 2), lam(3), grad_u(2, 2), hat(2, 3), contact_k, nonc1_k, nonc2_k, pos_ll
      integer(ip) :: t, b, n_blocks, n, i
      integer :: k, alpha

      n = p%n
      n_blocks = (mesh%nt_owned + block - 1)/block
      allocate (partial(3, n_blocks))
      !$omp parallel do default(none) shared(mesh, p, x, c_omega, mu, n, n_blocks, partial) &
      !$omp private(b, t, k, i, alpha, frame, uv, lam, grad_u, hat, contact_k, nonc1_k, nonc2_k, pos_ll) schedule(static)
      do b = 1, n_blocks
         partial(:, b) = 0.0_dp
         do t = (b - 1)*block + 1, min(b*block, mesh%nt_owned)
            do k = 1, 3
               i = p%unknown(mesh%triangles(k, t))
               if (i > 0) then
                  uv(k, :) = [x(i), x(n + i)]
                  lam(k) = x(2*n + i)
               else
                  uv(k, :) = [p%g, 0.0_dp]
                  lam(k) = 0.0_dp
               end if
            end do
            ! the expression with which the estimators form ∇u_α for the element pass
            hat = p1_gradients(mesh, t)
            do alpha = 1, 2
               grad_u(:, alpha) = matmul(hat, uv(:, alpha))
            end do
            frame = frame_of(mesh%vertices, mesh%triangles(:, t))
            call iterate_parts(frame, hat, c_omega, mu, uv, lam, grad_u, contact_k, nonc1_k, nonc2_k, pos_ll)
            partial(:, b) = partial(:, b) + [nonc1_k**2, nonc2_k**2, pos_ll]
         end do
      end do
      !$omp end parallel do
      sums = 0.0_dp
      do b = 1, n_blocks
         sums = sums + partial(:, b)
      end do
   end function iterate_sums

   !> The global η_nonc,1, η_nonc,2, η_nonc,3 from Σ η_nonc,1,K², Σ η_nonc,2,K² and ‖λ⁺‖² (summed
   !> over the ranks), c_omega = C; η_lin = η_nonc,1 + η_nonc,2 + η_nonc,3^{1/2}. One place for
   !> both the element pass and the η_lin pass, so that their η_lin agree by construction.
   pure subroutine nonconformity(nonc1_sq, nonc2_sq, positive_sq, c_omega, nonc1, nonc2, nonc3, eta_lin)
      real(dp), intent(in) :: nonc1_sq, nonc2_sq, positive_sq, c_omega
      real(dp), intent(out) :: nonc1, nonc2, nonc3, eta_lin

      nonc1 = sqrt(nonc1_sq)
      nonc2 = sqrt(nonc2_sq)
      nonc3 = 2*c_omega*sqrt(positive_sq)*nonc1
      eta_lin = nonc1 + nonc2 + sqrt(nonc3)
   end subroutine nonconformity

   !> Exact ∫_{l>0} l w and ∫_{l>0} l² over a triangle for linear l and w given at its vertices:
   !> clip at l = 0 and integrate the quadratics with the edge-midpoint rule on a fan.
   pure subroutine sign_split(p, l, w, int_lw, int_ll)
      real(dp), intent(in) :: p(2, 3), l(3), w(3)
      real(dp), intent(out) :: int_lw, int_ll

      real(dp) :: pts(2, 4), lv(4), wv(4), s, area, lm, wm
      integer :: i, j, np, k, e
      integer, parameter :: ends(2, 3) = reshape([0, 1, 1, 2, 2, 0], [2, 3])
      integer :: fan(0:2)

      np = 0
      do i = 1, 3
         j = modulo(i, 3) + 1
         if (l(i) >= 0.0_dp) then
            np = np + 1
            pts(:, np) = p(:, i)
            lv(np) = l(i)
            wv(np) = w(i)
         end if
         if ((l(i) > 0.0_dp .and. l(j) < 0.0_dp) .or. (l(i) < 0.0_dp .and. l(j) > 0.0_dp)) then
            s = l(i)/(l(i) - l(j))
            np = np + 1
            pts(:, np) = p(:, i) + s*(p(:, j) - p(:, i))
            lv(np) = 0.0_dp
            wv(np) = w(i) + s*(w(j) - w(i))
         end if
      end do
      int_lw = 0.0_dp
      int_ll = 0.0_dp
      do k = 2, np - 1
         area = 0.5_dp*abs((pts(1, k) - pts(1, 1))*(pts(2, k + 1) - pts(2, 1)) - &
                           (pts(1, k + 1) - pts(1, 1))*(pts(2, k) - pts(2, 1)))
         fan = [1, k, k + 1]
         do e = 1, 3
            lm = 0.5_dp*(lv(fan(ends(1, e))) + lv(fan(ends(2, e))))
            wm = 0.5_dp*(wv(fan(ends(1, e))) + wv(fan(ends(2, e))))
            int_lw = int_lw + area/3*lm*wm
            int_ll = int_ll + area/3*lm**2
         end do
      end do
   end subroutine sign_split

end module twomem_estimate_iterate_parts
