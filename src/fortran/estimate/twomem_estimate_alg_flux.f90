!> The algebraic flux reconstruction σ_α,alg with ∇·σ_α,alg = r_α exactly (paper §4.3; thesis
!> Def. 1.4.8; Papež, Rüde, Vohralík, Wohlmuth, CMAME 2020): one V-cycle-like sweep over the
!> last meshes T_b ⊂ … ⊂ T_J of the nested hierarchy. First the Riesz representer ρ_α of r_α
!> among P1 functions on T_b (one UMFPACK solve, factorized once); then, for j = b+1..J, on the
!> patch of every vertex a of T_{j−1}, an RT_p problem on the triangles of T_j in that patch
!> with divergence (I − Π_{j−1})(r_α ψ_a − ∇ρ_α·∇ψ_a), Π_{j−1} the L² projection onto
!> P_p(T_{j−1}) and Π_b := 0. These divergences add up level by level to (Π_j − Π_{j−1}) r_α and
!> in total to r_α. With a single mesh (b = J) the patches are those of T_J itself, which gives
!> ∇·σ = Π_p r_α. Integrals of r_α over coarser triangles go through its L² projection onto
!> P2 of each triangle, which is exact against the quadratic ψ_a q of the patch data. The
!> patch problems use the operators of the shape classes (twomem_estimate_shapes), and so do
!> these projections and the patch data: every integral involved is one of scaled monomials
!> and barycentric coordinates, its class's times the area ratio, so no quadrature runs here.
!> The refined levels' patches are twomem_estimate_alg_refined's, the finest mesh's (b = J)
!> twomem_estimate_alg_single's. When the coarse problem would be too large to factorize, the
!> one-level construction replaces it on the finest mesh: ρ̃_α by conjugate gradients, the
!> remainder bounded by η_rem (twomem_estimate_riesz; docs/method.md §3). The level parts and
!> the P2 fields are kept between evaluations.
!> On a rank's piece of a distributed hierarchy: the restriction of R_α starts from the finest
!> vertices the rank owns (each vertex counted once over the ranks), the parts are summed at
!> the shared coarse unknowns, and the coarse problem is solved whole on rank 0
!> (twomem_linalg_gathered_solve), which returns ρ_α at every local vertex of T_b, ghost layer
!> included, so that ∇ρ_α is right on every triangle of a rank's patches. The patches are those
!> of the vertices of the rank's own triangles (twomem_estimate_coloring), whose data the
!> caller has made whole on the ghost triangles (the lifting r, twomem_estimate_evaluated_iterate).
module twomem_estimate_alg_flux
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_linalg_gathered_solve, only: gathered_solver_t
   use twomem_linalg_umfpack, only: ordering_minimum_degree
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t, n_p2
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_patch_classes, only: patch_table_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t
   use twomem_estimate_alg_refined, only: p2_field_t, project_p2, level_patches
   use twomem_estimate_generic_patch, only: generic_scratch_t
   use twomem_estimate_alg_single, only: single_mesh_patches
   use twomem_estimate_riesz, only: riesz_representer_t
   use twomem_estimate_ghosts, only: ghost_cells_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_operators, only: preconditioner_t
   implicit none
   private

   public :: algebraic_flux_t, level_flux_t

   !> σ_alg's part on one level: coefficients (n_flux, nt_l, 2) on the triangles of T_l.
   type :: level_flux_t
      integer :: level = 0
      real(dp), allocatable :: sigma(:, :, :)
   end type level_flux_t

   type :: vector_t
      real(dp), allocatable :: v(:)
   end type vector_t

   type :: algebraic_flux_t
      !> the coarsest level used (b) and the finest (J)
      integer :: base = 0, finest = 0
      type(rt_space_t) :: space
      type(comm_t) :: comm
      type(discrete_problem_t) :: coarse
      type(gathered_solver_t) :: coarse_solver
      !> the vertices of T_b where the coarse solve returns ρ_α: the unknowns, then (distributed)
      !> the interior vertices of the ghost layer only
      integer(ip), allocatable :: rho_vertices(:)
      !> the finest vertices this rank owns: it restricts their residuals
      logical, allocatable :: fine_owned(:)
      !> vertex colourings of the meshes whose vertices carry patches (first−1..finest−1, or J)
      type(coloring_t), allocatable :: colors(:)
      !> the result of the last `compute`, level by level (first..finest), and its workspaces
      type(level_flux_t), allocatable :: levels(:)
      type(p2_field_t), allocatable :: p2(:)
      real(dp), allocatable :: grad_rho(:, :, :)
      !> R_α of the evaluated iterate (`take_residual`), both membranes: restricted to T_{J−1},
      !> or at the unknowns of T_J when b = J; the nodal residuals themselves are not kept (the
      !> evaluated iterate turns them into their patch shares in place: 16 MB at 10⁶ vertices)
      real(dp), allocatable :: top(:, :)
      logical :: has_residual = .false.
      !> workspaces of the coarse Riesz representer: R_α restricted to T_l (l = b..J−2), the
      !> coarse right-hand side and solution, ρ_α at the vertices of T_b
      type(vector_t), allocatable :: restricted(:)
      real(dp), allocatable :: coarse_rhs(:), rho(:), nodal(:)
      !> the one-level construction (b = J without a coarse solve: twomem_estimate_riesz), and
      !> what it needs: h_Ω C_PF, the tensions, the flux order
      logical :: one_level = .false.
      type(riesz_representer_t) :: riesz
      real(dp) :: poincare = 1.0_dp, mu(2) = 1.0_dp
   contains
      procedure :: init
      procedure :: take_residual
      procedure :: compute
      procedure :: one_level_source
      procedure :: first
      procedure :: free_levels
      procedure :: drop_solvers
   end type algebraic_flux_t

contains

   !> Use the last `n_meshes` meshes of the hierarchy (all when fewer); factorize the coarse
   !> Laplacian, colour the patch meshes (the level parts are allocated by the first `compute`).
   !> Without `classes` (the hierarchy stores no shape classes, which the refined levels' patches
   !> read) a single mesh. When the coarse problem would have more than `exact_max` unknowns over
   !> all ranks and more than a sixteenth of the finest mesh's, the one-level construction
   !> replaces it on the finest mesh (twomem_estimate_riesz, with poincare = h_Ω C_PF). With `comm`, the hierarchy is this rank's piece of a distributed
   !> one (collective).
   subroutine init(self, space, hierarchy, data, n_meshes, classes, exact_max, poincare, err, comm)
      class(algebraic_flux_t), intent(out) :: self
      type(rt_space_t), intent(in) :: space
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      integer, intent(in) :: n_meshes
      logical, intent(in) :: classes
      integer(ip), intent(in) :: exact_max
      real(dp), intent(in) :: poincare
      type(error_t), allocatable, intent(out) :: err
      type(comm_t), intent(in), optional :: comm

      integer :: j, first
      integer(ip) :: a
      integer(ip), allocatable :: ghost_only(:)
      logical, allocatable :: inside(:)

      if (present(comm)) self%comm = comm
      self%space = space
      self%poincare = poincare
      self%mu = [data%mu1, data%mu2]
      self%finest = hierarchy%levels
      ! a mesh without interior vertices has no coarse problem (its ρ_α would be zero)
      self%base = max(0, self%finest - n_meshes + 1, hierarchy%first_with_unknowns(self%comm))
      if (.not. classes) self%base = self%finest
      ! the coarse problem of the default three meshes is a sixteenth of the finest one: it
      ! stays exact whatever its size, a whole-mesh one only up to exact_max unknowns
      if (unknowns(hierarchy%meshes(self%base), self%comm) > &
          max(exact_max, unknowns(hierarchy%meshes(self%finest), self%comm)/16)) then
         self%one_level = .true.
         self%base = self%finest
      end if
      first = self%first()
      allocate (self%colors(first:self%finest), self%levels(self%finest - first + 1), self%p2(first:self%finest))
      do j = first, self%finest
         ! the patches of level j live on the vertices of level j − 1 (of J itself for one mesh)
         call self%colors(j)%init(hierarchy%meshes(merge(j, j - 1, j == self%base)))
         self%levels(j - first + 1)%level = j
      end do
      ! the one-level construction solves on the finest problem the caller passes to `compute`
      if (self%one_level) return
      allocate (self%grad_rho(2, hierarchy%meshes(self%base)%nt, 2))
      associate (base_mesh => hierarchy%meshes(self%base), fine_mesh => hierarchy%meshes(self%finest))
         call self%coarse%init(base_mesh, data, err, self%comm)
         call self%comm%agree(err)
         if (allocated(err)) return
         inside = base_mesh%in_subdomain()
         ghost_only = pack([(a, a=1, base_mesh%nv)], .not. (inside .or. base_mesh%boundary_vertex))
         self%rho_vertices = [self%coarse%interior, ghost_only]
         ! factorized once per run: METIS's analysis would cost more than its smaller factor
         ! saves in a handful of solves, so minimum degree. No iterative refinement: the Poisson
         ! matrix is SPD and well conditioned, the solve's backward error is round-off without
         ! it, and UMFPACK's one step tripled every solve (docs/performance.md)
         call self%coarse_solver%init(self%comm, base_mesh%global_vertex_of(self%rho_vertices), &
                                      [self%coarse%halo%owned, spread(.false., 1, size(ghost_only))], &
                                      ordering_minimum_degree, refinement_steps=0)
         ! (a loop: this file puts array temporaries on the stack)
         allocate (self%fine_owned(fine_mesh%nv))
         do a = 1, fine_mesh%nv
            self%fine_owned(a) = fine_mesh%vertex_owner_of(a) == self%comm%rank
         end do
         allocate (self%nodal(base_mesh%nv))
      end associate
      allocate (self%restricted(self%base:self%finest - 2))
      do j = self%base, self%finest - 2
         allocate (self%restricted(j)%v(hierarchy%meshes(j)%nv))
      end do
      if (self%base == self%finest) then
         allocate (self%top(self%coarse%n, 2))
      else
         allocate (self%top(hierarchy%meshes(self%finest - 1)%nv, 2))
      end if
      allocate (self%coarse_rhs(size(self%rho_vertices)), self%rho(size(self%rho_vertices)))
      self%coarse_rhs = 0.0_dp
      call self%coarse_solver%factor(self%coarse%stiffness, err)
   end subroutine init

   !> The unknowns (interior vertices) of `mesh` over all ranks, each counted by its owner.
   integer(ip) function unknowns(mesh, comm) result(n)
      type(mesh_t), intent(in) :: mesh
      type(comm_t), intent(in) :: comm

      integer(ip) :: a

      n = 0
      do a = 1, mesh%nv
         if (.not. mesh%boundary_vertex(a) .and. mesh%vertex_owner_of(a) == comm%rank) n = n + 1
      end do
      n = nint(comm%sum(real(n, dp)), ip)
   end function unknowns

   !> The one-level construction's source for the evaluated iterate (its residual taken): the
   !> Riesz representer riesz%rho that the patches read (twomem_estimate_riesz, solved on p with
   !> `halo`, `ghosts` and `precond` as in `compute`), and room for σ_alg in levels(1)%sigma.
   !> The patches themselves follow: `compute`, or the discretization flux's pass, which solves
   !> them on its own factorizations (twomem_estimate_disc_flux). Collective.
   subroutine one_level_source(self, hierarchy, p, halo, ghosts, err, precond)
      class(algebraic_flux_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(discrete_problem_t), intent(in) :: p
      type(halo_t), intent(inout) :: halo
      type(ghost_cells_t), intent(in) :: ghosts
      type(error_t), allocatable, intent(out) :: err
      class(preconditioner_t), intent(inout), optional :: precond

      if (.not. (self%has_residual .and. self%one_level)) then
         call make_error(err, exit_io, 'algebraic flux', 'internal: no one-level residual to represent')
         return
      end if
      associate (mesh => hierarchy%meshes(self%finest), lev => self%levels(1))
         call self%riesz%solve(mesh, self%finest, p, halo, ghosts, self%top, self%poincare, self%mu, &
                               self%space%order, err, precond)
         if (allocated(err)) return
         if (.not. allocated(lev%sigma)) allocate (lev%sigma(self%space%n_flux, mesh%nt, 2))
      end associate
   end subroutine one_level_source

   !> self%levels returns σ_alg level by level (levels b+1..J, or J alone with a single mesh)
   !> for the evaluated iterate: from its nodal algebraic residuals, zero at boundary vertices,
   !> and their lifting r on T_J. The patches use the factors of their signatures
   !> (twomem_estimate_patch_classes) in `single` (the finest mesh) and `refined` (the coarse
   !> meshes of the refined levels); on the finest mesh, patches without a signature take the
   !> generic path with the threads' `scratch`, on the refined levels they are assembled and
   !> factorized on their own. The one-level construction solves on p (the finest problem, with
   !> `halo` a copy of its halo and `ghosts` the ghost layer) with the preconditioner `precond`
   !> of p's stiffness, or none.
   subroutine compute(self, shapes, hierarchy, iterate, single, refined, scratch, p, halo, ghosts, err, precond)
      class(algebraic_flux_t), intent(inout) :: self
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(evaluated_iterate_t), intent(in) :: iterate
      type(patch_table_t), intent(in) :: single, refined
      type(generic_scratch_t), intent(inout) :: scratch(0:)
      type(discrete_problem_t), intent(in) :: p
      type(halo_t), intent(inout) :: halo
      type(ghost_cells_t), intent(in) :: ghosts
      type(error_t), allocatable, intent(out) :: err
      class(preconditioner_t), intent(inout), optional :: precond

      integer :: j, first
      logical :: ok
      real(dp) :: none(0, 0, 0)

      if (.not. self%has_residual) then
         call make_error(err, exit_io, 'algebraic flux', 'internal: compute before take_residual')
         return
      end if
      if (self%one_level) then
         call self%one_level_source(hierarchy, p, halo, ghosts, err, precond)
         if (allocated(err)) return
         associate (mesh => hierarchy%meshes(self%finest), lev => self%levels(1))
            call single_mesh_patches(self%space, shapes, single, mesh, self%finest, self%colors(self%finest), scratch, &
                                     self%riesz%rho, .true., none, lev%sigma, ok)
         end associate
         if (.not. ok) call make_error(err, exit_io, 'algebraic flux', 'a patch system is singular (degenerate triangles?)')
         return
      end if
      call coarse_representer(self, hierarchy, err)
      if (allocated(err)) return
      first = self%first()
      ! at the first computation: the solver may have released its memory for them by then
      ! (twomem_newton_inner), and a run that never needs the algebraic flux never holds them
      do j = first, self%finest
         if (.not. allocated(self%levels(j - first + 1)%sigma)) &
            allocate (self%levels(j - first + 1)%sigma(self%space%n_flux, hierarchy%meshes(j)%nt, 2))
         ! on T_J itself r is P1: its P2 projection is r, never stored
         if (j < self%finest .and. .not. allocated(self%p2(j)%c)) &
            allocate (self%p2(j)%c(n_p2, hierarchy%meshes(j)%nt, 2))
      end do
      call project_p2(shapes, hierarchy, first, iterate, self%p2)
      do j = first, self%finest
         associate (lev => self%levels(j - first + 1))
            if (j == self%base) then
               ! a single mesh: patches and triangles of T_J
               call single_mesh_patches(self%space, shapes, single, hierarchy%meshes(j), j, self%colors(j), scratch, iterate, &
                                        .false., self%grad_rho, lev%sigma, ok)
            else if (j == first) then
               call level_patches(self%space, shapes, refined, hierarchy%meshes(j - 1), hierarchy%meshes(j), j, &
                                  self%colors(j), .true., self%grad_rho, self%p2(j), self%p2(j), iterate, lev%sigma, ok)
            else
               call level_patches(self%space, shapes, refined, hierarchy%meshes(j - 1), hierarchy%meshes(j), j, &
                                  self%colors(j), .false., self%grad_rho, self%p2(j - 1), self%p2(j), iterate, lev%sigma, ok)
            end if
         end associate
         if (.not. ok) then
            call make_error(err, exit_io, 'algebraic flux', 'a patch system is singular (degenerate triangles?)')
            return
         end if
         ! the levels above read the P2 fields of j and up only: room for the finest level's part
         if (j > first .and. j < self%finest) deallocate (self%p2(j - 1)%c)
      end do
   end subroutine compute

   !> The level parts and P2 fields go (the next `compute` allocates them again).
   subroutine free_levels(self)
      class(algebraic_flux_t), intent(inout) :: self

      integer :: i, j

      if (allocated(self%levels)) then
         do i = 1, size(self%levels)
            if (allocated(self%levels(i)%sigma)) deallocate (self%levels(i)%sigma)
         end do
      end if
      if (allocated(self%p2)) then
         do j = lbound(self%p2, 1), ubound(self%p2, 1)
            if (allocated(self%p2(j)%c)) deallocate (self%p2(j)%c)
         end do
      end if
      call self%riesz%free()
   end subroutine free_levels

   !> After the last `compute`: what only a computation reads goes (the coarse factorization, the
   !> P2 fields, ∇ρ_α, the representer's and colourings' arrays); `levels`, its result, stays for
   !> the element pass. A later `compute` would need `init` again.
   subroutine drop_solvers(self)
      class(algebraic_flux_t), intent(inout) :: self

      integer :: j

      call self%coarse_solver%release_factor()
      if (allocated(self%p2)) then
         do j = lbound(self%p2, 1), ubound(self%p2, 1)
            if (allocated(self%p2(j)%c)) deallocate (self%p2(j)%c)
         end do
      end if
      if (allocated(self%restricted)) deallocate (self%restricted)
      if (allocated(self%top)) deallocate (self%top)
      self%has_residual = .false.
      if (allocated(self%colors)) deallocate (self%colors)
      if (allocated(self%grad_rho)) deallocate (self%grad_rho)
      call self%riesz%free()
   end subroutine drop_solvers

   !> The first level with patch problems: b + 1, or J for a single mesh.
   pure integer function first(self)
      class(algebraic_flux_t), intent(in) :: self

      first = min(self%base + 1, self%finest)
   end function first

   !> Keep what the algebraic flux needs of the nodal residuals R_α (zero off the unknowns) of
   !> the iterate of this evaluation, before the iterate turns them into patch shares: their
   !> restriction to T_{J−1} (the transpose of prolongation; each finest vertex counted on the
   !> rank that owns it, so the coarser sums are parts over the ranks), or their values at the
   !> unknowns of T_J for a single mesh. A later `compute` is for this iterate.
   subroutine take_residual(self, hierarchy, residual, interior)
      class(algebraic_flux_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      real(dp), intent(in) :: residual(:, :)
      !> the finest problem's unknowns (their vertices)
      integer(ip), intent(in) :: interior(:)

      integer :: alpha
      integer(ip) :: v, i

      if (self%one_level .and. .not. allocated(self%top)) allocate (self%top(size(interior), 2))
      ! one membrane per thread: each sums into its own column, in the same order as alone
      !$omp parallel do default(none) shared(self, hierarchy, residual, interior) private(alpha, v, i) schedule(static, 1)
      do alpha = 1, 2
         if (self%one_level) then
            do i = 1, size(interior, kind=ip)
               self%top(i, alpha) = residual(interior(i), alpha)
            end do
            cycle
         else if (self%base == self%finest) then
            do i = 1, self%coarse%n
               self%top(i, alpha) = residual(self%coarse%interior(i), alpha)
            end do
            cycle
         end if
         associate (parents => hierarchy%maps(self%finest)%vertex_parents, coarse => self%top(:, alpha))
            coarse = 0.0_dp
            do v = 1, hierarchy%meshes(self%finest)%nv
               if (.not. self%fine_owned(v)) cycle
               coarse(parents(1, v)) = coarse(parents(1, v)) + 0.5_dp*residual(v, alpha)
               coarse(parents(2, v)) = coarse(parents(2, v)) + 0.5_dp*residual(v, alpha)
            end do
         end associate
      end do
      !$omp end parallel do
      self%has_residual = .true.
   end subroutine take_residual

   !> ∇ρ_α on the triangles of T_b: (∇ρ_α, ∇v) = (r_α, v) for the P1 functions v of T_b vanishing
   !> on ∂Ω. Since (r_α, ψ_{J,l}) = R_α(l), the right-hand side is R_α restricted level by level
   !> (the transpose of prolongation), from its restriction to T_{J−1} (`take_residual`).
   subroutine coarse_representer(self, hierarchy, err)
      class(algebraic_flux_t), intent(inout) :: self
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(error_t), allocatable, intent(out) :: err

      integer :: alpha, l
      integer(ip) :: v, i

      associate (base_mesh => hierarchy%meshes(self%base))
         do alpha = 1, 2
            ! R_α restricted level by level into the kept workspaces (restricted(l) on T_l)
            do l = self%finest - 2, self%base, -1
               associate (parents => hierarchy%maps(l + 1)%vertex_parents, coarse => self%restricted(l)%v)
                  coarse = 0.0_dp
                  if (l == self%finest - 2) then
                     do v = 1, hierarchy%meshes(l + 1)%nv
                        coarse(parents(1, v)) = coarse(parents(1, v)) + 0.5_dp*self%top(v, alpha)
                        coarse(parents(2, v)) = coarse(parents(2, v)) + 0.5_dp*self%top(v, alpha)
                     end do
                  else
                     do v = 1, hierarchy%meshes(l + 1)%nv
                        coarse(parents(1, v)) = coarse(parents(1, v)) + 0.5_dp*self%restricted(l + 1)%v(v)
                        coarse(parents(2, v)) = coarse(parents(2, v)) + 0.5_dp*self%restricted(l + 1)%v(v)
                     end do
                  end if
               end associate
            end do
            do i = 1, self%coarse%n
               if (self%base == self%finest) then
                  self%coarse_rhs(i) = self%top(i, alpha)
               else if (self%base == self%finest - 1) then
                  self%coarse_rhs(i) = self%top(self%coarse%interior(i), alpha)
               else
                  self%coarse_rhs(i) = self%restricted(self%base)%v(self%coarse%interior(i))
               end if
            end do
            ! the ranks' parts of the restricted residual at shared unknowns (full already on T_J)
            if (self%base < self%finest) call self%coarse%halo%add(self%coarse_rhs(1:self%coarse%n))
            call self%coarse_solver%solve(self%coarse_rhs, self%rho, err)
            if (allocated(err)) return
            self%nodal = 0.0_dp
            self%nodal(self%rho_vertices) = self%rho
            call representer_gradients(base_mesh, self%nodal, self%grad_rho(:, :, alpha))
         end do
      end associate
   end subroutine coarse_representer

   !> grad(:, t) = ∇ρ on every triangle t of `mesh`, ρ the P1 function with nodal values `nodal`.
   subroutine representer_gradients(mesh, nodal, grad)
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: nodal(:)
      real(dp), intent(out) :: grad(:, :)

      integer(ip) :: t

      !$omp parallel do default(none) shared(mesh, nodal, grad) private(t) schedule(static)
      do t = 1, mesh%nt
         grad(:, t) = matmul(p1_gradients(mesh, t), nodal(mesh%triangles(:, t)))
      end do
      !$omp end parallel do
   end subroutine representer_gradients

end module twomem_estimate_alg_flux
