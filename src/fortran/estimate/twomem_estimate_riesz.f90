!> The Riesz representer of the algebraic residual for the one-level algebraic flux, computed
!> approximately, with what its inexactness costs the bound (docs/method.md §3, "One-level
!> algebraic flux"; the idea of Papež, Strakoš and Vohralík, Numer. Math. 138, 2018). For each
!> membrane, preconditioned conjugate gradients on K ρ = R_α (K the stiffness on the unknowns of
!> the finest mesh, R_α the nodal algebraic residual) give ρ̃_α and leave the remainder
!> R'_α = R_α − K ρ̃_α. Its lifting r'_α (the lifting of twomem_estimate_lifting) enters the
!> bound through the Friedrichs inequality:
!>   η_rem = (Σ_α (h_Ω C_PF μ_α^{−1/2} ‖r'_α‖)²)^{1/2}    (RT0: ‖Π_0 r'_α‖),
!> while the patch problems of the flux are given r_α − r'_α, the lifting of K ρ̃_α, which is
!> compatible with ρ̃_α exactly. The iteration stops as soon as h_Ω C_PF ‖r'_α‖ is at most
!> `remainder_fraction` of ‖∇ρ̃_α‖ (the algebraic flux's size, known before any patch is
!> solved: μ_α^{−1/2}‖∇ρ̃_α‖ approximates η_alg,α), or after `max_iterations`: the bound holds
!> whatever the iteration did; only its sharpness depends on it. The result is held as an
!> evaluated iterate (twomem_estimate_evaluated_iterate) whose "u" is ρ̃ and whose shares are
!> those of K ρ̃, so that the patches read ∇ρ̃ and the lifting of K ρ̃ on every triangle, the
!> ghost layer's from their owners. Distributed: K is each rank's part, its products summed at
!> shared unknowns, the conjugate gradients' products over owned entries, the norms over own
!> triangles, and the ranks stop together.
module twomem_estimate_riesz
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_operators, only: summed_csr_operator_t, preconditioner_t, identity_preconditioner_t, &
      distributed_product_t
   use twomem_linalg_pcg, only: pcg_solve, pcg_options_t, pcg_monitor_t, pcg_test_t
   use twomem_estimate_lifting, only: lifting_on_triangle, patch_shares
   use twomem_estimate_ghosts, only: ghost_cells_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t
   implicit none
   private

   public :: riesz_representer_t, remainder_fraction, max_iterations

   !> the conjugate gradients stop once h_Ω C_PF ‖r'_α‖ ≤ remainder_fraction ‖∇ρ̃_α‖
   real(dp), parameter :: remainder_fraction = 0.05_dp
   !> ... or after this many iterations (a V-cycle preconditioner needs a handful)
   integer, parameter :: max_iterations = 100

   type :: riesz_representer_t
      !> u(:, α) = ρ̃_α (nodal, zero off the unknowns), shares(:, α) = the patch shares of K ρ̃_α
      type(evaluated_iterate_t) :: rho
      !> ‖r'_α‖ (RT0: ‖Π_0 r'_α‖), and h_Ω C_PF ‖r'_α‖ μ_α^{−1/2} combined: η_rem
      real(dp) :: remainder(2) = 0.0_dp, eta = 0.0_dp
      !> the last solve's iterations per membrane
      integer :: iterations(2) = 0
   contains
      procedure :: solve
      procedure :: free
   end type riesz_representer_t

   !> The conjugate gradients' stopping test (see the module header).
   type, extends(pcg_test_t) :: remainder_test_t
      type(mesh_t), pointer :: mesh => null()
      type(discrete_problem_t), pointer :: p => null()
      type(comm_t) :: comm
      real(dp), pointer :: b(:) => null()
      real(dp) :: poincare = 1.0_dp
      integer :: order = 1
      !> the lifting's norm at the last test, and the nodal shares it was computed from
      real(dp) :: norm = 0.0_dp
      real(dp), allocatable :: shares(:, :)
   contains
      procedure :: done => remainder_done
   end type remainder_test_t

contains

   !> ρ̃_α for both membranes, from the residuals r(:, α) at the unknowns of p (full values at
   !> shared ones), the preconditioner of K given or, without, none. poincare: h_Ω C_PF; mu: the
   !> tensions; order: the flux's (RT0 measures Π_0 r'). Collective.
   subroutine solve(self, mesh, level, p, halo, ghosts, r, poincare, mu, order, err, precond)
      class(riesz_representer_t), intent(inout) :: self
      type(mesh_t), target, intent(in) :: mesh
      integer, intent(in) :: level
      type(discrete_problem_t), target, intent(in) :: p
      type(halo_t), target, intent(inout) :: halo
      type(ghost_cells_t), intent(in) :: ghosts
      real(dp), target, intent(in) :: r(:, :)
      real(dp), intent(in) :: poincare, mu(2)
      integer, intent(in) :: order
      type(error_t), allocatable, intent(out) :: err
      class(preconditioner_t), intent(inout), optional, target :: precond

      type(summed_csr_operator_t) :: k_op
      type(distributed_product_t) :: dot
      type(remainder_test_t) :: test
      type(pcg_options_t) :: options
      type(pcg_monitor_t) :: monitor
      type(identity_preconditioner_t), target :: none
      class(preconditioner_t), pointer :: m
      real(dp), allocatable :: x(:), kx(:)
      integer(ip) :: i, n
      integer :: alpha

      n = p%n
      if (.not. allocated(self%rho%u)) call self%rho%init(mesh)
      k_op%a => p%stiffness
      k_op%halo => halo
      dot%comm = halo%comm
      dot%owned = halo%owned
      if (present(precond)) then
         m => precond
      else
         m => none
      end if
      test%mesh => mesh
      test%p => p
      test%comm = halo%comm
      test%poincare = poincare
      test%order = order
      allocate (test%shares(mesh%nv, 1))
      options%max_it = max_iterations
      allocate (x(n), kx(n))
      self%rho%u = 0.0_dp
      self%rho%lambda = 0.0_dp
      do alpha = 1, 2
         test%b => r(:, alpha)
         x = 0.0_dp
         call pcg_solve(k_op, m, dot, r(:, alpha), x, options, monitor, err, test)
         if (allocated(err)) return
         self%iterations(alpha) = monitor%iterations
         ! the remainder of the returned iterate, R − K ρ̃ (not the recursively updated one)
         call k_op%apply(x, kx)
         test%shares = 0.0_dp
         self%rho%shares(:, alpha) = 0.0_dp
         do i = 1, n
            self%rho%u(p%interior(i), alpha) = x(i)
            test%shares(p%interior(i), 1) = r(i, alpha) - kx(i)
            ! the patches' source: the lifting of K ρ̃ = R − R'
            self%rho%shares(p%interior(i), alpha) = kx(i)
         end do
         call patch_shares(mesh, test%shares)
         self%remainder(alpha) = lifted_norm(mesh, test%shares, test%comm, order)
      end do
      self%eta = poincare*sqrt(sum(self%remainder**2/mu))
      call self%rho%set_shares(mesh)
      call self%rho%share_ghosts(ghosts, mesh, level)
   end subroutine solve

   subroutine free(self)
      class(riesz_representer_t), intent(inout) :: self

      call self%rho%free()
   end subroutine free

   !> h_Ω C_PF ‖r'‖ ≤ remainder_fraction ‖∇x‖ with r' the lifting of the residual r and
   !> ‖∇x‖² = xᵀ K x = xᵀ (b − r); or r = 0. Every rank decides alike (global sums).
   logical function remainder_done(self, iteration, x, r) result(done)
      class(remainder_test_t), intent(inout) :: self
      integer, intent(in) :: iteration
      real(dp), intent(in) :: x(:), r(:)

      real(dp) :: energy
      integer(ip) :: i

      self%shares = 0.0_dp
      energy = 0.0_dp
      do i = 1, self%p%n
         self%shares(self%p%interior(i), 1) = r(i)
         if (self%p%halo%owned(i)) energy = energy + x(i)*(self%b(i) - r(i))
      end do
      energy = self%comm%sum(energy)
      call patch_shares(self%mesh, self%shares)
      self%norm = lifted_norm(self%mesh, self%shares, self%comm, self%order)
      done = self%poincare*self%norm <= remainder_fraction*sqrt(max(0.0_dp, energy)) .or. self%norm == 0.0_dp
   end function remainder_done

   !> ‖r‖ (order 1) or ‖Π_0 r‖ (order 0) for the lifting r whose patch shares are `shares`
   !> (twomem_estimate_lifting), over this rank's own triangles, summed over the ranks. The
   !> lifting is P1 on each triangle with vertex values v: ‖r‖²_K = |K|/12 (Σ v_i² + (Σ v_i)²),
   !> ‖Π_0 r‖²_K = |K| (Σ v_i/3)². Summed by blocks of triangles in a fixed order: the same bits
   !> for any thread count.
   real(dp) function lifted_norm(mesh, shares, comm, order) result(norm)
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: shares(:, :)
      type(comm_t), intent(in) :: comm
      integer, intent(in) :: order

      integer(ip), parameter :: block = 1024
      real(dp), allocatable :: partial(:)
      real(dp) :: v(3, 1), s, acc
      integer(ip) :: t, b, n_blocks

      n_blocks = (mesh%nt_owned + block - 1)/block
      allocate (partial(n_blocks))
      !$omp parallel do default(none) shared(mesh, shares, order, partial, n_blocks) private(b, t, v, s, acc) &
      !$omp schedule(static)
      do b = 1, n_blocks
         acc = 0.0_dp
         do t = (b - 1)*block + 1, min(b*block, mesh%nt_owned)
            call lifting_on_triangle(mesh, shares, t, v)
            s = v(1, 1) + v(2, 1) + v(3, 1)
            if (order == 0) then
               acc = acc + mesh%area(t)*(s/3)**2
            else
               acc = acc + mesh%area(t)/12*(v(1, 1)**2 + v(2, 1)**2 + v(3, 1)**2 + s**2)
            end if
         end do
         partial(b) = acc
      end do
      !$omp end parallel do
      norm = sqrt(max(0.0_dp, comm%sum(sum(partial))))
   end function lifted_norm
end module twomem_estimate_riesz
