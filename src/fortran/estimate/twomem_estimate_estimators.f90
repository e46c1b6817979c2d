!> The a posteriori estimators of the paper (Theorem 5.1, Corollary 5.6) for an arbitrary
!> iterate X of any of the Newton methods: from X, the algebraic residual lifting, the
!> discretization and algebraic flux reconstructions, then per triangle and in total
!>   η_F,K,α   = ‖μ_α^{1/2}∇u_α + μ_α^{−1/2}σ_α‖_K   (σ = σ_disc + σ_alg),
!>   η_osc,K,α = (h_K/π) μ_α^{−1/2}‖f_α − Π_p f_α‖_K  (RT0: of f_α ∓ λ_h, see below),
!>   η_C,K     = 2(λ⁺, u1 − u2)_K   (signed; summed, never squared),
!>   η_nonc,1,K = |||s_h − u_h|||_K,  η_nonc,2,K = C‖λ⁻‖_K,  η_nonc,3,K = 2C‖λ⁺‖_Ω η_nonc,1,K,
!> with s_h the nodewise projection onto u1 ≥ u2 (the mean where u1 < u2) and
!> C = h_Ω C_PF (1/μ1 + 1/μ2)^{1/2}. The caller passes h_Ω C_PF: a Poincaré–Friedrichs constant
!> of the domain, ‖v‖ ≤ h_Ω C_PF ‖∇v‖ on H¹_0 (see `poincare_constant`).
!> The guaranteed bound is η = {(η_1 + η_nonc,1 + η_nonc,2)² + η_nonc,3 + Σ_K η_C,K}^{1/2} (41),
!> split into η_disc, η_lin, η_alg with η ≤ η_disc + η_lin + η_alg (Cor. 5.6, p = 1).
!> The parts of λ_h are integrated exactly (each triangle clipped at λ_h = 0), not by quadrature.
!> With RT0 the fluxes only match the means of f_α ∓ λ_h − r_α, so the oscillation term takes
!> the whole f_α ∓ λ_h − Π_0(f_α ∓ λ_h) (r_α drops out: σ_alg carries Π_0 r_α): the bound stays
!> guaranteed, at the price of a λ_h-dependent term.
!> Distributed (a communicator given to `init`): each rank evaluates the patches of the vertices
!> of its own triangles, which are whole on its piece thanks to the ghost layer, with ∇u_h and
!> the residual lifting of the ghost triangles copied from their owners
!> (twomem_estimate_evaluated_iterate); it computes the element estimators on its own triangles only, and
!> every global value is a sum or maximum over the ranks, so all ranks see the same totals and
!> take the same decisions. The per-triangle values of the local criteria are copied to the
!> ghost triangles too, so that a vertex's patch test sees its whole patch.
module twomem_estimate_estimators
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: domain_disk, domain_square, bound_paper, bound_root, bound_sharp
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_linalg_halo, only: halo_t
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, frame_of
   use twomem_estimate_lifting, only: algebraic_residuals
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, gradients_on
   use twomem_estimate_disc_flux, only: discretization_flux, load_moments_t
   use twomem_estimate_alg_flux, only: algebraic_flux_t, level_flux_t
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_ghosts, only: ghost_cells_t
   use twomem_estimate_patch_classes, only: patch_table_t
   use twomem_estimate_iterate_parts, only: iterate_parts, iterate_sums, nonconformity
   use twomem_estimate_estimates, only: estimates_t
   use twomem_estimate_generic_patch, only: generic_scratch_t
   use twomem_estimate_triangle_ops, only: rt_mass_matrix
   use twomem_estimate_storage, only: storage_tier, max_single_shapes, tier_none, tier_single, tier_all
   use twomem_estimate_element_terms, only: data_oscillation, quadratic_forms, add_in_child_basis
   use twomem_estimate_multiplier, only: multiplier_factors, multiplier_on
   use twomem_estimate_flux_correction, only: correct_flux
   use twomem_linalg_operators, only: preconditioner_t
   use omp_lib, only: omp_get_max_threads
   implicit none
   private

   public :: estimator_t, estimates_t, poincare_constant

   real(dp), parameter :: pi = acos(-1.0_dp)
   !> j_{1,1}, the first positive zero of J_1: ‖v − v_K‖_K ≤ (h_K/j_{1,1}) ‖∇v‖_K on every
   !> triangle K of diameter h_K (Laugesen and Siudeja 2010), sharper than convex domains' h_K/π
   real(dp), parameter :: bessel_j1_first_zero = 3.831705970207512_dp
   !> the sums of the element pass: see element_estimators
   integer, parameter :: n_sums = 9
   !> the algebraic flux's coarse problem is solved exactly (factorized once) up to this many
   !> unknowns, or up to a sixteenth of the finest mesh's (the default three meshes' coarse
   !> problem); above both, the one-level construction replaces it (docs/input.md,
   !> estimate.alg_levels). A factor of 2^14 unknowns takes a few MB and tens of milliseconds.
   integer(ip), parameter, public :: exact_coarse_max = 16384_ip

   type :: estimator_t
      type(rt_space_t) :: space
      type(algebraic_flux_t) :: alg
      !> the triangle operators of every level, per shape class, when the hierarchy stores them
      !> (`classes`); otherwise every patch takes the generic path, with the threads' scratch
      type(shape_classes_t) :: shapes
      logical :: classes = .false.
      type(generic_scratch_t), allocatable :: scratch(:)
      !> the signatures of the vertices' patches: on the finest mesh's own triangles
      !> (discretization flux, single-mesh algebraic flux) and on refined coarse triangles
      type(patch_table_t) :: single, refined
      !> the finest mesh's vertex colouring for the discretization-flux patches
      type(coloring_t) :: colors
      !> (f_α ψ_i, q_k)_K and, for RT1, (h_K/π)‖f_α − Π_1 f_α‖_K (data only, fixed on the mesh)
      type(load_moments_t) :: loads
      real(dp), allocatable :: osc_data(:, :)
      !> workspaces of `evaluate`, kept between evaluations (allocated by the first, freed by
      !> `free_workspaces`): σ_disc (n_flux, nt, 2) and the evaluated iterate's nodal fields
      real(dp), allocatable :: sigma(:, :, :)
      type(evaluated_iterate_t) :: iterate
      real(dp) :: mu(2) = 1, c_omega = 1
      !> estimate.bound (bound_paper, bound_root, bound_sharp) and the oscillation's constant
      !> over h_K that goes with it: 1/π, or 1/j_{1,1} for the triangles' Poincaré inequality
      integer :: bound = bound_paper
      real(dp) :: osc_constant = 1/pi
      !> the ranks (one by default), the copies to the ghost triangles, and a copy of the
      !> discrete problem's halo for the residual's products
      type(comm_t) :: comm
      type(ghost_cells_t) :: ghosts
      type(halo_t) :: halo
      logical :: has_halo = .false.
      !> `end_evaluations` has dropped what evaluations need
      logical :: ended = .false.
   contains
      procedure :: init
      procedure :: evaluate
      procedure :: element_fields
      procedure :: complete
      procedure :: linearization_estimate
      procedure :: free_workspaces
      procedure :: end_evaluations
      procedure :: holds
   end type estimator_t

contains

   !> h_Ω C_PF with ‖v‖ ≤ h_Ω C_PF ‖∇v‖ on H¹_0: 1/j_{0,1} on the unit disk (sharp; it also holds
   !> on the inscribed polygon, a subset), √2/π on the square (−1,1)² (sharp), and otherwise the
   !> diameter over π, safe for any domain (Ω lies in a strip of that width, where the
   !> one-dimensional Friedrichs inequality applies across the strip).
   pure real(dp) function poincare_constant(domain, diameter) result(c)
      !> domain_disk, domain_square or domain_gmsh
      integer, intent(in) :: domain
      real(dp), intent(in) :: diameter

      real(dp), parameter :: bessel_j0_first_zero = 2.404825557695773_dp

      select case (domain)
      case (domain_disk)
         c = 1/bessel_j0_first_zero
      case (domain_square)
         c = sqrt(2.0_dp)/pi
      case default
         c = diameter/pi
      end select
   end function poincare_constant

   !> flux_order 0 or 1; alg_meshes: how many of the finest meshes the algebraic flux uses;
   !> poincare: h_Ω C_PF. With `comm`, the hierarchy is this rank's piece of a distributed one
   !> (collective; every rank returns the same error). `tier` and `exact_max` override the
   !> choices of what is stored for the patch problems (storage_tier) and of the algebraic
   !> flux's exact coarse solve (exact_coarse_max), for tests that compare the paths.
   subroutine init(self, hierarchy, data, flux_order, alg_meshes, poincare, err, comm, tier, exact_max, bound)
      class(estimator_t), intent(out) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      integer, intent(in) :: flux_order, alg_meshes
      real(dp), intent(in) :: poincare
      type(error_t), allocatable, intent(out) :: err
      type(comm_t), intent(in), optional :: comm
      integer, intent(in), optional :: tier
      integer(ip), intent(in), optional :: exact_max
      !> estimate.bound: bound_paper (default), bound_root or bound_sharp
      integer, intent(in), optional :: bound

      integer(ip) :: coarse_max
      integer :: stored

      if (present(comm)) self%comm = comm
      if (present(bound)) self%bound = bound
      if (self%bound /= bound_paper) self%osc_constant = 1/bessel_j1_first_zero
      call self%ghosts%init(self%comm, hierarchy%meshes(0))
      associate (mesh => hierarchy%meshes(hierarchy%levels))
         call self%space%init(flux_order)
         self%mu = [data%mu1, data%mu2]
         self%c_omega = poincare*sqrt(1/data%mu1 + 1/data%mu2)
         ! a single mesh shares classes only where its triangles repeat (an adapted mesh's
         ! bisections do, a mesher's triangles do not): found by shape, up to what the budget holds
         if (hierarchy%levels == 0) then
            if (present(tier)) then
               if (tier /= tier_none) call self%shapes%classify(mesh, int(mesh%nt))
            else
               call self%shapes%classify(mesh, max_single_shapes(mesh, flux_order))
            end if
         end if
         if (present(tier)) then
            stored = tier
         else
            stored = storage_tier(hierarchy, flux_order, alg_meshes, self%comm, self%shapes%n_shapes())
         end if
         if (stored == tier_none) call self%shapes%free()
         self%classes = stored /= tier_none
         if (self%classes) then
            call self%shapes%init(self%space, hierarchy, err, multilevel=stored == tier_all)
            call self%comm%agree(err)
            if (allocated(err)) return
         end if
         allocate (self%scratch(0:omp_get_max_threads() - 1))
         call self%colors%init(mesh)
         call self%loads%init(self%space, mesh, data)
         ! (constant loads are their own projection: no oscillation to store)
         if (flux_order == 1 .and. .not. self%loads%constant) &
            call data_oscillation(self%space, mesh, data, self%mu, self%osc_data, self%osc_constant)
         coarse_max = exact_coarse_max
         if (present(exact_max)) coarse_max = exact_max
         call self%alg%init(self%space, hierarchy, data, alg_meshes, stored == tier_all, coarse_max, poincare, err, &
                            self%comm)
         call self%comm%agree(err)
         if (allocated(err)) return
         if (self%classes) call patch_tables(self, hierarchy, err)
         call self%comm%agree(err)
         if (allocated(err)) return
         ! without refined levels every patch without a signature takes the generic path
         if (stored == tier_single) call self%shapes%keep_factored_only()
      end associate
   end subroutine init


   !> The patch signatures of every patch mesh: the finest mesh for the discretization flux (and
   !> the single-mesh algebraic flux), the coarse meshes of the refined algebraic-flux levels.
   subroutine patch_tables(self, hierarchy, err)
      type(estimator_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(error_t), allocatable, intent(out) :: err

      integer :: j, finest

      finest = hierarchy%levels
      call self%single%init(.false., finest)
      call self%single%add_mesh(self%space, self%shapes, hierarchy%meshes(finest), hierarchy%meshes(finest), finest)
      call self%single%finish(self%space, self%shapes, err)
      if (allocated(err)) return
      call self%refined%init(.true., finest)
      if (self%alg%base < finest) then
         do j = self%alg%first(), finest
            call self%refined%add_mesh(self%space, self%shapes, hierarchy%meshes(j - 1), hierarchy%meshes(j), j - 1)
         end do
      end if
      call self%refined%finish(self%space, self%shapes, err)
   end subroutine patch_tables


   !> Every estimator for the iterate x = [X1; X2; X3] of the discrete problem p on the finest
   !> mesh. Collective (every rank returns the same error). With `fields` (the default) also the
   !> per-triangle values: right on the rank's own triangles, and on the ghost ones for the
   !> arrays of the local criteria (disc_k, alg_k, lin_k); the other arrays are zero there.
   !> Without, only the totals (what the global stopping tests read), and no per-triangle array
   !> is held: `element_fields` adds them later for this same iterate. With algebraic = .false.
   !> the algebraic flux, about half of an evaluation, is left out: est then holds η_disc and
   !> η_lin (with their parts) but no η_alg nor bound, and no fields; `complete` adds the rest
   !> for this same iterate.
   subroutine evaluate(self, hierarchy, data, p, x, est, err, fields, algebraic, precond)
      class(estimator_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:)
      !> its per-triangle arrays are reused when they have the mesh's size
      type(estimates_t), intent(inout) :: est
      type(error_t), allocatable, intent(out) :: err
      logical, intent(in), optional :: fields, algebraic
      !> a preconditioner of p's stiffness for the one-level algebraic flux (see `complete`)
      class(preconditioner_t), intent(inout), optional :: precond

      integer(ip) :: n
      integer :: correction_iterations(2)
      logical :: ok, with_fields, with_alg, one_pass

      call refuse_after_end(self, err)
      if (allocated(err)) return
      with_alg = .true.
      if (present(algebraic)) with_alg = algebraic
      with_fields = with_alg
      if (present(fields)) with_fields = fields .and. with_alg
      n = p%n
      if (.not. self%has_halo) then
         self%halo = p%halo
         self%has_halo = .true.
      end if
      if (.not. allocated(self%sigma)) call allocate_workspaces(self, hierarchy%meshes(hierarchy%levels))
      associate (mesh => hierarchy%meshes(hierarchy%levels), it => self%iterate)
         ! the residuals R_α go where their patch shares will be, with u_1's room (set next) as
         ! the scratch on their way; the algebraic flux keeps what it needs of them before
         ! set_shares turns them into their shares in place
         call algebraic_residuals(p, x, it%shares, it%u(:, 1), self%halo)
         call self%alg%take_residual(hierarchy, it%shares, p%interior)
         call it%set_shares(mesh)
         call scatter(p, x(1:n), p%g, it%u(:, 1))
         call scatter(p, x(n + 1:2*n), 0.0_dp, it%u(:, 2))
         call scatter(p, x(2*n + 1:3*n), 0.0_dp, it%lambda)
         ! a ghost triangle may have vertices outside this rank's unknowns: its owner's values
         call it%share_ghosts(self%ghosts, mesh, hierarchy%levels)
         if (self%bound == bound_sharp) call multiplier_factors(mesh, it)

         ! the one-level algebraic flux's patches are the discretization flux's systems with other
         ! data: its source first, then one pass for both
         one_pass = with_alg .and. self%alg%one_level
         if (one_pass) then
            call self%alg%one_level_source(hierarchy, p, self%halo, self%ghosts, err, precond)
            call self%comm%agree(err)
            if (allocated(err)) return
            call discretization_flux(self%space, self%shapes, self%single, mesh, hierarchy%levels, self%colors, &
                                     self%mu, self%loads, it, self%scratch, self%sigma, ok, &
                                     alg_source=self%alg%riesz%rho, alg_sigma=self%alg%levels(1)%sigma)
         else
            call discretization_flux(self%space, self%shapes, self%single, mesh, hierarchy%levels, self%colors, &
                                     self%mu, self%loads, it, self%scratch, self%sigma, ok)
         end if
         if (self%comm%any_true(.not. ok)) then
            call make_error(err, exit_io, 'discretization flux', 'a patch system is singular (degenerate triangles?)')
            return
         end if
         ! 'sharp': the divergence-free correction that brings σ_α closer to −μ_α∇u_αh
         if (self%bound == bound_sharp) then
            call correct_flux(self%space%order, mesh, p, self%halo, self%sigma, correction_iterations, err)
            if (allocated(err)) return
         end if
      end associate
      if (one_pass) then
         call element_pass(self, hierarchy, data, est, with_fields, .true.)
      else if (with_alg) then
         call self%complete(hierarchy, data, est, err, with_fields, p, precond)
      else
         call element_pass(self, hierarchy, data, est, .false., .false.)
      end if
   end subroutine evaluate

   !> The algebraic flux and every estimator for the iterate of the last evaluation, which left
   !> it out (or to be recomputed from its residual): see `evaluate`. p: the discrete problem of
   !> that evaluation, on which the one-level algebraic flux solves its Riesz problem
   !> (twomem_estimate_riesz) with `precond`, a preconditioner of p's stiffness (without one,
   !> plain conjugate gradients). Collective.
   subroutine complete(self, hierarchy, data, est, err, fields, p, precond)
      class(estimator_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      type(estimates_t), intent(inout) :: est
      type(error_t), allocatable, intent(out) :: err
      logical, intent(in) :: fields
      type(discrete_problem_t), intent(in) :: p
      class(preconditioner_t), intent(inout), optional :: precond

      call refuse_after_end(self, err)
      if (allocated(err)) return
      call self%alg%compute(self%shapes, hierarchy, self%iterate, self%single, self%refined, self%scratch, p, self%halo, &
                            self%ghosts, err, precond)
      call self%comm%agree(err)
      if (allocated(err)) return
      call element_pass(self, hierarchy, data, est, fields, .true.)
   end subroutine complete

   !> The workspaces of `evaluate` on the finest mesh (the algebraic flux allocates its own).
   subroutine allocate_workspaces(self, mesh)
      type(estimator_t), intent(inout) :: self
      type(mesh_t), intent(in) :: mesh

      allocate (self%sigma(self%space%n_flux, mesh%nt, 2))
      call self%iterate%init(mesh)
   end subroutine allocate_workspaces

   !> The workspaces of the evaluations (about 0.8 KiB per vertex with RT1: σ_disc, the algebraic
   !> flux's level parts, ∇u_α and the lifting per triangle, nodal copies) go, for a phase that
   !> needs the memory after the last evaluation (the output); the next `evaluate` allocates
   !> them again. `complete` and `element_fields` need the workspaces of their evaluation: a
   !> caller that frees them evaluates afresh.
   subroutine free_workspaces(self)
      class(estimator_t), intent(inout) :: self

      if (allocated(self%sigma)) deallocate (self%sigma)
      call self%iterate%free()
      call self%alg%free_levels()
   end subroutine free_workspaces

   !> After the run's last evaluation, of which only the element pass may still run
   !> (`element_fields`): what else evaluations need goes, the patch factors, the shape classes'
   !> patch operators and the algebraic flux's coarse factorization and P2 fields (0.25 KiB per
   !> vertex with RT1), so that the per-triangle fields do not meet it. Evaluating afterwards is
   !> an error.
   subroutine end_evaluations(self)
      class(estimator_t), intent(inout) :: self

      self%ended = .true.
      if (allocated(self%scratch)) deallocate (self%scratch)
      call self%single%free()
      call self%refined%free()
      call self%alg%drop_solvers()
      call self%shapes%keep_mass_only()
   end subroutine end_evaluations

   !> After `end_evaluations` an evaluation is a caller's mistake, not a numerical failure.
   subroutine refuse_after_end(self, err)
      type(estimator_t), intent(in) :: self
      type(error_t), allocatable, intent(inout) :: err

      if (self%ended) call make_error(err, exit_io, 'estimators', 'internal: an evaluation after end_evaluations')
   end subroutine refuse_after_end

   !> Whether the workspaces' nodal copies are those of iterate x (this rank's unknowns), as after
   !> an evaluation of x: the test by which a caller reuses an evaluation without keeping a copy
   !> of its iterate (an evaluation that failed may have left them so: the caller knows).
   logical function holds(self, p, x)
      class(estimator_t), intent(in) :: self
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:)

      integer(ip) :: i, n

      holds = allocated(self%iterate%u)
      if (.not. holds) return
      n = p%n
      do i = 1, n
         associate (a => p%interior(i), it => self%iterate)
            if (it%u(a, 1) /= x(i) .or. it%u(a, 2) /= x(n + i) .or. it%lambda(a) /= x(2*n + i)) then
               holds = .false.
               return
            end if
         end associate
      end do
   end function holds

   !> η_lin = η_nonc,1 + η_nonc,2 + η_nonc,3^{1/2} of iterate x alone. It needs no flux, only one
   !> pass over the triangles with the element pass's own expressions (iterate_parts), so it
   !> equals a whole evaluation's η_lin to round-off at about a fiftieth of its cost: the
   !> adaptive method weighs it against the last η_disc to decide whether a check is worth an
   !> evaluation. It reads x directly (no nodal copies), so the last evaluation's workspaces,
   !> which `element_fields` may still read, stay untouched. Collective.
   function linearization_estimate(self, hierarchy, p, x) result(eta_lin)
      class(estimator_t), intent(in) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:)
      real(dp) :: eta_lin

      real(dp) :: sums(3), nonc1, nonc2, nonc3

      sums = iterate_sums(hierarchy%meshes(hierarchy%levels), p, x, self%c_omega, self%mu)
      call self%comm%sum_in_place(sums)
      call nonconformity(sums(1), sums(2), sums(3), self%c_omega, nonc1, nonc2, nonc3, eta_lin)
   end function linearization_estimate

   !> The per-triangle fields of `est`, the last evaluation (made without them): its fluxes and
   !> nodal fields are still held here, so only the element pass runs again (about a tenth of an
   !> evaluation), with the same totals. Collective.
   subroutine element_fields(self, hierarchy, data, est)
      class(estimator_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      type(estimates_t), intent(inout) :: est

      call element_pass(self, hierarchy, data, est, .true., .true.)
   end subroutine element_fields

   !> The element estimators from the fluxes and nodal fields of the last evaluation, their
   !> totals over the ranks and, with `fields`, the per-triangle arrays; without `algebraic`
   !> (and then without fields), the algebraic flux is taken as absent and only what does not
   !> depend on it is kept.
   subroutine element_pass(self, hierarchy, data, est, fields, algebraic)
      type(estimator_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      type(estimates_t), intent(inout) :: est
      logical, intent(in) :: fields, algebraic

      real(dp) :: positive_norm, lin_factor, sums(n_sums), nan

      if (fields) then
         call est%ensure(hierarchy%meshes(hierarchy%levels)%nt)
      else
         call est%drop_fields()
      end if
      if (algebraic) then
         call element_estimators(self, hierarchy, data, self%sigma, self%alg%levels, est, sums)
      else
         ! no level of algebraic flux: the disc, contact and nonconformity sums are the same
         call element_estimators(self, hierarchy, data, self%sigma, self%alg%levels(1:0), est, sums)
      end if
      ! the rank's own triangles, summed over the ranks
      call self%comm%sum_in_place(sums)
      positive_norm = sqrt(sums(9))
      est%eta_1 = sqrt(sums(1))
      ! the one-level algebraic flux's remainder (twomem_estimate_riesz) adds to the flux part
      ! of the bound and to the algebraic component: η_1 + η_rem, η_alg + η_rem
      est%alg_remainder = 0.0_dp
      if (algebraic .and. self%alg%one_level) est%alg_remainder = self%alg%riesz%eta
      est%flux = sqrt(sums(2))
      est%osc = sqrt(sums(3))
      est%contact = sums(4)
      call nonconformity(sums(5), sums(6), sums(9), self%c_omega, est%nonc1, est%nonc2, est%nonc3, est%lin)
      est%total = bound_of(self%bound, est%eta_1 + est%alg_remainder + est%nonc1 + est%nonc2, est%nonc3 + est%contact)
      est%disc = sqrt(sums(7)) + sqrt(abs(est%contact))
      est%alg = sqrt(sums(8)) + est%alg_remainder
      est%complete = algebraic
      if (.not. algebraic) then
         nan = ieee_value(1.0_dp, ieee_quiet_nan)
         est%alg = nan
         est%total = nan
         est%eta_1 = nan
         est%alg_remainder = nan
         est%flux = nan
      end if
      if (.not. fields) return
      est%nonc3_k = 2*self%c_omega*positive_norm*est%nonc1_k
      ! (65a): the local linearization estimator whose criterion implies the global one
      lin_factor = 1.0_dp
      if (est%nonc1 > 0.0_dp) lin_factor = 1 + sqrt(2*self%c_omega*positive_norm/est%nonc1)
      est%lin_k = lin_factor*est%nonc1_k + est%nonc2_k
      ! the local criteria's values on the ghost triangles, from their owners
      call self%ghosts%fill(hierarchy%levels, est%disc_k)
      call self%ghosts%fill(hierarchy%levels, est%alg_k)
      call self%ghosts%fill(hierarchy%levels, est%lin_k)
   end subroutine element_pass

   !> The bound from the proof's last inequality e² ≤ A e + c/2 (A = η_1 + η_rem + η_nonc,1 +
   !> η_nonc,2, c = η_nonc,3 + Σ η_C,K): the paper's (41), √(A² + c), through AB ≤ (A² + B²)/2,
   !> or the inequality's exact root A/2 + √(A²/4 + c/2), never larger (docs/method.md §3).
   pure real(dp) function bound_of(bound, a, c) result(eta)
      integer, intent(in) :: bound
      real(dp), intent(in) :: a, c

      if (bound == bound_paper) then
         eta = sqrt(max(0.0_dp, a**2 + c))
      else
         eta = a/2 + sqrt(max(0.0_dp, a**2/4 + c/2))
      end if
   end function bound_of

   !> The nodal field of the interior values x (discrete_problem_t%to_nodal into a kept array).
   subroutine scatter(p, x, boundary_value, u)
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:), boundary_value
      real(dp), intent(out) :: u(:)

      integer(ip) :: i

      u = boundary_value
      do i = 1, p%n
         u(p%interior(i)) = x(i)
      end do
   end subroutine scatter

   !> The per-triangle parts on the rank's own triangles (zero on the ghost ones), stored in
   !> est's arrays when it has them, and this rank's sums of them: `sums` = Σ(η_F + η_osc)²,
   !> Ση_F², Ση_osc², Ση_C, Ση_nonc,1², Ση_nonc,2², Σ(η_disc + η_osc)², Ση_alg² (both membranes)
   !> and ‖λ⁺‖². The sums go by blocks of `block` triangles in a fixed order, so that they do not
   !> depend on the thread count nor on whether the arrays are kept. The flux norms are exact
   !> quadratic forms with the shape class's RT mass matrix: μ_α∇u_α is constant on K, so it is
   !> the combination of the constant basis fields φ_1, φ_2, and each coarser level's σ_alg is
   !> rewritten in K's own basis (`add_in_child_basis`), RT_p being closed under restriction.
   subroutine element_estimators(self, hierarchy, data, sigma, levels, est, sums)
      class(estimator_t), intent(in) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      real(dp), intent(in) :: sigma(:, :, :)
      type(level_flux_t), intent(in) :: levels(:)
      type(estimates_t), intent(inout) :: est
      real(dp), intent(out) :: sums(n_sums)

      integer(ip), parameter :: block = 1024

      type(rt_frame_t) :: frame, level_frames(size(levels))
      real(dp) :: x(2), w, sq(3, 2), f(2), lam_x, osc_mean(2), osc_sq(2), osc_w, ratio
      real(dp) :: c_disc(self%space%n_flux), c_alg(self%space%n_flux)
      !> K's barycentre in each ancestor's scaled coordinates and the ratio of their scales
      real(dp) :: shift(2, size(levels)), kappa(size(levels))
      real(dp) :: pos_ll, inv_ratio_sq, uv(3, 2), lam(3), grad_k(2, 2), hat(2, 3)
      !> K's RT mass matrix where no shape class holds it
      real(dp) :: mass(self%space%n_flux, self%space%n_flux)
      !> f ∓ λ_h at the 7 points of the degree-5 rule (RT0 only)
      real(dp) :: osc_values(2, 7)
      !> one triangle's parts: η_disc,K,α, η_alg,K,α, η_F,K,α, η_osc,K,α; η_C,K, η_nonc,1,K, η_nonc,2,K
      real(dp) :: disc_k(2), alg_k(2), flux_k(2), osc_k(2), contact_k, nonc1_k, nonc2_k
      real(dp), allocatable :: partial(:, :)
      real(dp), parameter :: lambda_sign(2) = [1.0_dp, -1.0_dp]
      integer(ip) :: t, anc, generations(size(levels)), frame_anc(size(levels)), ancestors(size(levels)), b, n_blocks
      integer :: k, j, alpha, class
      integer(ip) :: v(3)
      integer :: finest
      integer(ip) :: nt_own
      logical :: fields

      finest = hierarchy%levels
      nt_own = hierarchy%meshes(finest)%nt_owned
      fields = est%has_fields()
      if (fields) then
         est%disc_k(:, nt_own + 1:) = 0.0_dp
         est%alg_k(:, nt_own + 1:) = 0.0_dp
         est%flux_k(:, nt_own + 1:) = 0.0_dp
         est%osc_k(:, nt_own + 1:) = 0.0_dp
         est%contact_k(nt_own + 1:) = 0.0_dp
         est%nonc1_k(nt_own + 1:) = 0.0_dp
         est%nonc2_k(nt_own + 1:) = 0.0_dp
      end if
      ! the ancestor of finest triangle t on level l is (t − 1)/4^(J−l) + 1 (children 4(t−1)+1..4t)
      do j = 1, size(levels)
         generations(j) = 4_ip**(finest - levels(j)%level)
      end do
      n_blocks = (nt_own + block - 1)/block
      allocate (partial(n_sums, n_blocks))
      ! no ancestor's frame computed yet (per thread)
      frame_anc = 0
      !$omp parallel do default(none) &
      !$omp shared(self, hierarchy, data, sigma, levels, est, finest, generations, nt_own) &
      !$omp shared(n_blocks, partial, fields) &
      !$omp private(b, t, anc, k, j, alpha, v, frame, level_frames, x, w, sq, f, lam_x, osc_mean, osc_sq, ratio, class) &
      !$omp private(c_disc, c_alg, shift, kappa, ancestors, osc_w, pos_ll, osc_values) &
      !$omp private(inv_ratio_sq, disc_k, alg_k, flux_k, osc_k, contact_k, nonc1_k, nonc2_k, uv, lam, grad_k, hat) &
      !$omp private(mass) firstprivate(frame_anc) schedule(static)
      do b = 1, n_blocks
         partial(:, b) = 0.0_dp
         do t = (b - 1)*block + 1, min(b*block, nt_own)
            v = hierarchy%meshes(finest)%triangles(:, t)
            frame = frame_of(hierarchy%meshes(finest)%vertices, v)
            if (self%classes) then
               call self%shapes%class_of(finest, t, class, ratio)
               inv_ratio_sq = 1.0_dp/ratio**2
            else
               call rt_mass_matrix(self%space, frame%vertices, mass)
            end if
            hat = p1_gradients(hierarchy%meshes(finest), t)
            call gradients_on(self%iterate, hierarchy%meshes(finest), t, hat, grad_k)
            do j = 1, size(levels)
               ! the ancestors' frames, once for both membranes and, since the children of a
               ! triangle are numbered consecutively, once per run of descendants in this thread's
               ! static block rather than once per finest triangle
               anc = (t - 1)/generations(j) + 1
               ancestors(j) = anc
               if (levels(j)%level /= finest) then
                  if (anc /= frame_anc(j)) then
                     frame_anc(j) = anc
                     associate (lm => hierarchy%meshes(levels(j)%level))
                        level_frames(j) = frame_of(lm%vertices, lm%triangles(:, anc))
                     end associate
                  end if
                  shift(:, j) = (frame%centre - level_frames(j)%centre)/level_frames(j)%scale
                  kappa(j) = frame%scale/level_frames(j)%scale
               end if
            end do
            do alpha = 1, 2
               c_disc = sigma(:, t, alpha)
               c_disc(1:2) = c_disc(1:2) + self%mu(alpha)*grad_k(:, alpha)
               c_alg = 0.0_dp
               do j = 1, size(levels)
                  if (levels(j)%level == finest) then
                     c_alg = c_alg + levels(j)%sigma(:, ancestors(j), alpha)
                  else
                     call add_in_child_basis(self%space%order, shift(:, j), kappa(j), &
                                             levels(j)%sigma(:, ancestors(j), alpha), c_alg)
                  end if
               end do
               ! the class mass matrix is that of the class size: K's is ρ⁻² times it
               if (self%classes) then
                  call quadratic_forms(self%space%n_flux, self%shapes%mass(:, :, class), c_disc, c_alg, sq(:, alpha))
                  sq(:, alpha) = sq(:, alpha)*inv_ratio_sq
               else
                  call quadratic_forms(self%space%n_flux, mass, c_disc, c_alg, sq(:, alpha))
               end if
            end do
            do alpha = 1, 2
               disc_k(alpha) = sqrt(max(0.0_dp, sq(1, alpha))/self%mu(alpha))
               alg_k(alpha) = sqrt(max(0.0_dp, sq(2, alpha))/self%mu(alpha))
               flux_k(alpha) = sqrt(max(0.0_dp, sq(3, alpha))/self%mu(alpha))
            end do
            ! contiguous copies: sections and vector subscripts as arguments cost a temporary each;
            ! lam: the multiplier the fluxes equilibrate with (λ_h, or λ̃ with bound = 'sharp')
            do k = 1, 3
               uv(k, :) = self%iterate%u(v(k), :)
            end do
            if (self%bound == bound_sharp) then
               call multiplier_on(self%iterate, hierarchy%meshes(finest), t, lam)
            else
               do k = 1, 3
                  lam(k) = self%iterate%lambda(v(k))
               end do
            end if
            if (self%space%order == 0 .and. self%loads%constant) then
               ! RT0, constant loads: f_α ∓ λ_h deviates from its mean as λ_h does, and for a
               ! linear function ∫_K (l − l̄)² = |K|/36 Σ_{i<j} (l_i − l_j)² (what the degree-5
               ! rule below gives, up to round-off, without 14 load evaluations per triangle)
               associate (lv => lam)
                  osc_sq = ((lv(1) - lv(2))**2 + (lv(2) - lv(3))**2 + (lv(3) - lv(1))**2)*frame%area/36
               end associate
               osc_k = frame%scale*self%osc_constant*sqrt(osc_sq/self%mu)
            else if (self%space%order == 0) then
               ! RT0: the oscillation of f_α ∓ λ_h around its mean
               osc_mean = 0.0_dp
               osc_sq = 0.0_dp
               do k = 1, self%space%rule%n
                  x = matmul(frame%vertices, self%space%rule%bary(:, k))
                  w = self%space%rule%weights(k)*frame%area
                  lam_x = dot_product(lam, self%space%rule%bary(:, k))
                  f = [data%load(1, x), data%load(2, x)] + lambda_sign*lam_x
                  osc_values(:, k) = f
                  osc_mean = osc_mean + w*f
               end do
               osc_mean = osc_mean/frame%area
               do k = 1, self%space%rule%n
                  osc_w = self%space%rule%weights(k)*frame%area
                  osc_sq = osc_sq + osc_w*(osc_values(:, k) - osc_mean)**2
               end do
               osc_k = frame%scale*self%osc_constant*sqrt(osc_sq/self%mu)
            else if (allocated(self%osc_data)) then
               osc_k = self%osc_data(:, t)
            else
               osc_k = 0.0_dp
            end if

            call iterate_parts(frame, hat, self%c_omega, self%mu, uv, lam, grad_k, contact_k, nonc1_k, nonc2_k, pos_ll)
            partial(:, b) = partial(:, b) + [sum((flux_k + osc_k)**2), sum(flux_k**2), sum(osc_k**2), contact_k, &
                                             nonc1_k**2, nonc2_k**2, sum((disc_k + osc_k)**2), sum(alg_k**2), pos_ll]
            if (fields) then
               est%disc_k(:, t) = disc_k
               est%alg_k(:, t) = alg_k
               est%flux_k(:, t) = flux_k
               est%osc_k(:, t) = osc_k
               est%contact_k(t) = contact_k
               est%nonc1_k(t) = nonc1_k
               est%nonc2_k(t) = nonc2_k
            end if
         end do
      end do
      !$omp end parallel do
      sums = 0.0_dp
      do b = 1, n_blocks
         sums = sums + partial(:, b)
      end do
   end subroutine element_estimators



end module twomem_estimate_estimators
