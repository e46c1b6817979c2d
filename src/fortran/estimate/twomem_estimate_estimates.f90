!> The result of one estimator evaluation (`estimates_t`): the global values of the paper's
!> Corollary 5.6 and the bound (41), and, when asked for, the per-triangle fields of the output's
!> `/estimators` and of the local stopping criteria. Kept apart from the evaluation
!> (twomem_estimate_estimators), which fills it: its users (the Newton observer, the local
!> criteria, the output) need the values, not the fluxes behind them.
module twomem_estimate_estimates
   use twomem_base_kinds, only: dp, ip
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t
   implicit none
   private

   public :: estimates_t

   !> One evaluation: global values and the per-triangle fields of `/estimators`.
   type :: estimates_t
      !> .false. after an evaluation without the algebraic flux (`evaluate` with algebraic =
      !> .false.): disc, lin and the parts they are made of hold, alg, total, eta_1 and flux are NaN
      logical :: complete = .true.
      !> the components of Cor. 5.6 and the bound (41)
      real(dp) :: disc = 0, lin = 0, alg = 0, total = 0
      !> the parts: η_1, ‖η_F‖, ‖η_osc‖, Σ η_C, η_nonc,1..3
      real(dp) :: eta_1 = 0, flux = 0, osc = 0, contact = 0, nonc1 = 0, nonc2 = 0, nonc3 = 0
      !> η_rem, the one-level algebraic flux's remainder (docs/method.md §3): part of alg and of
      !> the bound's flux part (η_1 + η_rem in (41)); zero otherwise. Global: it has no elements.
      real(dp) :: alg_remainder = 0
      !> per triangle, for each membrane: η_disc,K,α (without oscillation), η_alg,K,α, η_F,K,α, η_osc,K,α
      real(dp), allocatable :: disc_k(:, :), alg_k(:, :), flux_k(:, :), osc_k(:, :)
      !> per triangle: η_C,K, η_nonc,β,K and η_lin,K of the local criteria (65a)
      real(dp), allocatable :: contact_k(:), nonc1_k(:), nonc2_k(:), nonc3_k(:), lin_k(:)
   contains
      procedure :: local_criteria
      procedure :: field
      procedure :: has_fields
      procedure :: ensure
      procedure :: drop_fields
      procedure :: hand_over
   end type estimates_t

contains

   !> The local stopping criteria (64) of the paper: (64a) η_alg,ω_a,α ≤ min_{K ⊂ ω_a} γ_alg
   !> max(η_disc,K,α, η_lin,K) on every vertex patch and membrane; (64b) η_lin,K ≤ γ_lin min_α
   !> η_disc,K,α on every triangle. Distributed (`comm`): each rank tests its own triangles and
   !> the patches of their vertices (whose ghost triangles carry their owners' values), and the
   !> ranks agree (collective).
   subroutine local_criteria(self, mesh, gamma_alg, gamma_lin, alg_ok, lin_ok, comm)
      class(estimates_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: gamma_alg, gamma_lin
      logical, intent(out) :: alg_ok, lin_ok
      type(comm_t), intent(in), optional :: comm

      integer(ip) :: a, m, t, nt_own
      integer :: alpha
      real(dp) :: patch_alg, bound

      nt_own = mesh%nt_owned
      lin_ok = all(self%lin_k(1:nt_own) <= gamma_lin*minval(self%disc_k(:, 1:nt_own), dim=1))
      alg_ok = .true.
      vertices: do a = 1, mesh%nv
         ! the vertices of own triangles (the others' patches are not whole here)
         if (minval(mesh%patch_triangles(mesh%patch_ptr(a):mesh%patch_ptr(a + 1) - 1)) > nt_own) cycle
         do alpha = 1, 2
            patch_alg = 0.0_dp
            bound = huge(1.0_dp)
            do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
               t = mesh%patch_triangles(m)
               patch_alg = patch_alg + self%alg_k(alpha, t)**2
               bound = min(bound, gamma_alg*max(self%disc_k(alpha, t), self%lin_k(t)))
            end do
            if (sqrt(patch_alg) > bound) then
               alg_ok = .false.
               exit vertices
            end if
         end do
      end do vertices
      if (present(comm)) then
         alg_ok = .not. comm%any_true(.not. alg_ok)
         lin_ok = .not. comm%any_true(.not. lin_ok)
      end if
   end subroutine local_criteria

   !> Whether the per-triangle arrays hold this evaluation's values (an evaluation for the
   !> global stopping tests leaves them out: `estimator_t%element_fields`).
   pure logical function has_fields(self)
      class(estimates_t), intent(in) :: self

      has_fields = allocated(self%lin_k)
   end function has_fields

   !> No per-triangle arrays (their 13 numbers per triangle are the largest part of an
   !> evaluation's result, and only the output and the local criteria read them).
   subroutine drop_fields(self)
      class(estimates_t), intent(inout) :: self

      if (allocated(self%lin_k)) deallocate (self%disc_k, self%alg_k, self%flux_k, self%osc_k, self%contact_k, &
                                             self%nonc1_k, self%nonc2_k, self%nonc3_k, self%lin_k)
   end subroutine drop_fields

   !> `to` gets this evaluation with its per-triangle arrays moved, not copied (13 numbers per
   !> triangle, the largest part of it): `self` keeps the global values only.
   subroutine hand_over(self, to)
      class(estimates_t), intent(inout) :: self
      type(estimates_t), intent(out) :: to

      type(estimates_t) :: fields

      call move_fields(self, fields)
      to = self
      call move_fields(fields, to)
   end subroutine hand_over

   subroutine move_fields(from, to)
      type(estimates_t), intent(inout) :: from, to

      call move_alloc(from%disc_k, to%disc_k)
      call move_alloc(from%alg_k, to%alg_k)
      call move_alloc(from%flux_k, to%flux_k)
      call move_alloc(from%osc_k, to%osc_k)
      call move_alloc(from%contact_k, to%contact_k)
      call move_alloc(from%nonc1_k, to%nonc1_k)
      call move_alloc(from%nonc2_k, to%nonc2_k)
      call move_alloc(from%nonc3_k, to%nonc3_k)
      call move_alloc(from%lin_k, to%lin_k)
   end subroutine move_fields

   !> Per-triangle arrays for nt triangles, kept when they are already of that size.
   subroutine ensure(self, nt)
      class(estimates_t), intent(inout) :: self
      integer(ip), intent(in) :: nt

      if (allocated(self%lin_k)) then
         if (size(self%lin_k, kind=ip) == nt) return
         deallocate (self%disc_k, self%alg_k, self%flux_k, self%osc_k, self%contact_k, self%nonc1_k, self%nonc2_k, &
                     self%nonc3_k, self%lin_k)
      end if
      allocate (self%disc_k(2, nt), self%alg_k(2, nt), self%flux_k(2, nt), self%osc_k(2, nt))
      allocate (self%contact_k(nt), self%nonc1_k(nt), self%nonc2_k(nt), self%nonc3_k(nt), self%lin_k(nt))
   end subroutine ensure

   !> The per-triangle field `name` of `/estimators` and its global value (docs/output.md).
   subroutine field(self, name, values, total)
      class(estimates_t), intent(in) :: self
      character(len=*), intent(in) :: name
      real(dp), allocatable, intent(out) :: values(:)
      real(dp), intent(out) :: total

      select case (name)
      case ('eta_disc')
         values = sqrt(sum((self%disc_k + self%osc_k)**2, dim=1) + abs(self%contact_k))
         total = self%disc
      case ('eta_lin')
         values = self%lin_k
         total = self%lin
      case ('eta_alg')
         values = sqrt(sum(self%alg_k**2, dim=1))
         total = self%alg
      case ('eta_total')
         values = sqrt(sum((self%flux_k + self%osc_k)**2, dim=1) + abs(self%contact_k)) + self%lin_k
         total = self%total
      case ('eta_F')
         values = sqrt(sum(self%flux_k**2, dim=1))
         total = self%flux
      case ('eta_osc')
         values = sqrt(sum(self%osc_k**2, dim=1))
         total = self%osc
      case ('eta_C')
         values = self%contact_k
         total = self%contact
      case ('eta_nonc1')
         values = self%nonc1_k
         total = self%nonc1
      case ('eta_nonc2')
         values = self%nonc2_k
         total = self%nonc2
      case default
         values = self%nonc3_k
         total = self%nonc3
      end select
   end subroutine field
end module twomem_estimate_estimates
