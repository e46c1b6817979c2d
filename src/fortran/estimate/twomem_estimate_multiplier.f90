!> The contact multiplier the fluxes equilibrate with `estimate.bound = 'sharp'` (docs/method.md
!> §3, *Sharper bounds*): instead of λ_h itself, λ̃ = Σ_a λ_h(a) w_a ψ_a, piecewise P1 and
!> discontinuous across edges, with weights w_a ≥ 0 that keep every lumped patch mass,
!> (w_a ψ_a, 1)_{ω_a} = |ω_a|/3, which is all a patch problem's solvability needs. Where a vertex
!> with λ_h(a) > 0 has some triangles of its patch in full contact (u1h ≤ u2h at their three
!> vertices) and others not, part θ of its mass moves onto the former: w_a = 1 + θ(|ω_a|/|ω_a^c| − 1)
!> there and 1 − θ on the rest of the patch; elsewhere w_a = 1 and λ̃ = λ_h. The contact term
!> 2(λ̃⁺, u1h − u2h) then loses part of what λ_h put across the free boundary, the main excess
!> of the bound (41) on coarse meshes. Whether a triangle is in contact depends on its own
!> vertex values only (`in_contact`; a ghost triangle of a distributed piece, some of whose
!> vertices lie outside the rank's unknowns, as its owner found it), so the weights need one
!> real per vertex. A rank computes them for the vertices of its own triangles, whose patches
!> are whole on its piece: the only patches and triangles it evaluates.
module twomem_estimate_multiplier
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, in_contact
   implicit none
   private

   public :: multiplier_factors, multiplier_weight, multiplier_on

   !> the fraction θ of such a vertex's mass that moves. Any θ in [0, 1] keeps w_a ≥ 0 and the
   !> masses, so the bound holds for each; θ trades the contact term (which falls like 1 − θ)
   !> against the flux term (the flux must carry the moved mass inside the patch). The best θ
   !> measured on the disk cases of bench/effectivity.py lies between 0.3 and 1 depending on
   !> the mesh, and 1/2 improves on θ = 0 (the paper) on each of them.
   real(dp), parameter :: moved = 0.5_dp

contains

   !> iterate%lambda_factor(a) = |ω_a|/|ω_a^c| where part of λ_h's mass moves (ω_a^c the
   !> triangles of ω_a in contact, neither empty nor the whole patch), 0 where it stays
   !> (w_a = 1), from the iterate's u_αh, λ_h and, on a distributed piece, its ghost triangles'
   !> contact (after `share_ghosts`). Right at the vertices whose patch is whole on the piece.
   subroutine multiplier_factors(mesh, iterate)
      type(mesh_t), intent(in) :: mesh
      type(evaluated_iterate_t), intent(inout) :: iterate

      integer(ip) :: a, m, t
      real(dp) :: whole, touching, factor

      !$omp parallel do default(none) shared(mesh, iterate) private(a, m, t, whole, touching, factor) &
      !$omp schedule(static)
      do a = 1, mesh%nv
         factor = 0.0_dp
         if (iterate%lambda(a) > 0.0_dp .and. .not. mesh%boundary_vertex(a)) then
            whole = 0.0_dp
            touching = 0.0_dp
            do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
               t = mesh%patch_triangles(m)
               whole = whole + mesh%area(t)
               if (in_contact(iterate, mesh, t)) touching = touching + mesh%area(t)
            end do
            if (touching > 0.0_dp .and. touching < whole) factor = whole/touching
         end if
         iterate%lambda_factor(a) = factor
      end do
      !$omp end parallel do
   end subroutine multiplier_factors

   !> w_a on triangle t of ω_a, for the factors of `multiplier_factors`.
   pure real(dp) function multiplier_weight(iterate, mesh, a, t) result(w)
      type(evaluated_iterate_t), intent(in) :: iterate
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: a, t

      w = 1.0_dp
      if (iterate%lambda_factor(a) == 0.0_dp) return
      if (in_contact(iterate, mesh, t)) then
         w = 1 + moved*(iterate%lambda_factor(a) - 1)
      else
         w = 1 - moved
      end if
   end function multiplier_weight

   !> lam(k) = λ̃ at the k-th vertex of triangle t (λ̃ is P1 on t, λ_h(a) w_a there).
   pure subroutine multiplier_on(iterate, mesh, t, lam)
      type(evaluated_iterate_t), intent(in) :: iterate
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp), intent(out) :: lam(3)

      integer :: k
      integer(ip) :: a

      do k = 1, 3
         a = mesh%triangles(k, t)
         lam(k) = iterate%lambda(a)*multiplier_weight(iterate, mesh, a, t)
      end do
   end subroutine multiplier_on
end module twomem_estimate_multiplier
