!> The iterate an estimator evaluation works on: nodal u_αh and λ_h, the patch shares of the nodal
!> algebraic residuals R_α (twomem_estimate_lifting), and per triangle of the finest mesh ∇u_αh
!> and the residual lifting r_α. The two per-triangle fields are not stored (they held 0.16 KiB
!> per vertex at the peak of a run): each is computed where it is read, in a few operations on
!> nodal values at the triangle's vertices, which the reading patch has in cache: u_αh, and for
!> r_α the shares R_α(a)/N_a, so that the division is made once per vertex rather than once per
!> triangle and reading patch. A ghost triangle of a rank's piece of a distributed mesh is the
!> exception: some of its vertices may lie outside the rank's unknowns, so its values are copies
!> of its owner's, exchanged once per evaluation (`share_ghosts`). Ghost triangles are the tail
!> t > nt_owned of every level (twomem_mesh_hierarchy numbers the descendants of the coarse
!> ghosts last).
module twomem_estimate_evaluated_iterate
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_lifting, only: patch_shares, lifting_on_triangle
   use twomem_estimate_ghosts, only: ghost_cells_t
   implicit none
   private

   public :: evaluated_iterate_t, gradients_on, lifting_on, in_contact

   !> u1h − u2h at a vertex counts as zero up to this fraction of |u1h| + |u2h|: the contact rows
   !> of the discrete problem make it zero up to round-off, of either sign. Only the sharpness of
   !> `estimate.bound = 'sharp'` depends on it: the contact term is integrated with the actual gap.
   real(dp), parameter :: gap_tolerance = 1.0e-10_dp

   type :: evaluated_iterate_t
      !> u(:, α) = u_αh with its boundary values, lambda = λ_h and shares(:, α) = the patch shares
      !> of R_α, on this rank's vertices: the caller writes R_α there (zero off the unknowns), and
      !> `set_shares` turns it into its shares in place (R_α itself is not kept: what the
      !> algebraic flux needs of it, it takes before)
      real(dp), allocatable :: u(:, :), lambda(:), shares(:, :)
      !> the weights of the multiplier the fluxes equilibrate with (twomem_estimate_multiplier):
      !> all zero (λ_h itself) unless `estimate.bound = 'sharp'`
      real(dp), allocatable :: lambda_factor(:)
      !> the owners' ∇u_α (ghost_grad(:, α, t − nt_owned)) and r_α (ghost_lift(:, α, ...)) on
      !> the ghost triangles t > nt_owned of the finest mesh (none on one rank)
      real(dp), allocatable :: ghost_grad(:, :, :), ghost_lift(:, :, :)
      !> whether the owner finds ghost triangle t in contact (ghost_contact(t − nt_owned), see
      !> `in_contact`)
      logical, allocatable :: ghost_contact(:)
      integer(ip) :: nt_owned = 0
   contains
      procedure :: init
      procedure :: free
      procedure :: set_shares
      procedure :: share_ghosts
   end type evaluated_iterate_t

contains

   !> Room for an iterate on `mesh` (the finest mesh, or this rank's piece of it).
   subroutine init(self, mesh)
      class(evaluated_iterate_t), intent(out) :: self
      type(mesh_t), intent(in) :: mesh

      integer(ip) :: n_ghost

      self%nt_owned = mesh%nt_owned
      n_ghost = mesh%nt - mesh%nt_owned
      allocate (self%u(mesh%nv, 2), self%lambda(mesh%nv), self%shares(mesh%nv, 2), &
                self%ghost_grad(2, 2, n_ghost), self%ghost_lift(3, 2, n_ghost), self%ghost_contact(n_ghost), &
                self%lambda_factor(mesh%nv))
      self%lambda_factor = 0.0_dp
   end subroutine init

   subroutine free(self)
      class(evaluated_iterate_t), intent(inout) :: self

      if (allocated(self%u)) deallocate (self%u, self%lambda, self%shares, self%ghost_grad, &
                                         self%ghost_lift, self%ghost_contact, self%lambda_factor)
      self%nt_owned = 0
   end subroutine free

   !> grad(:, α) = ∇u_αh on triangle t, whose P1 basis gradients are `hat` (p1_gradients).
   !> The same expression as for ∇s_h in the element estimators, so that ∇(s_h − u_h) is exactly
   !> zero where s_h = u_h in every build (η_nonc,3 takes a square root of it).
   pure subroutine gradients_on(self, mesh, t, hat, grad)
      type(evaluated_iterate_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: hat(2, 3)
      real(dp), intent(out) :: grad(2, 2)

      real(dp) :: values(3)
      integer :: alpha, k

      if (t > self%nt_owned) then
         grad = self%ghost_grad(:, :, t - self%nt_owned)
         return
      end if
      do alpha = 1, 2
         ! contiguous copies: a vector subscript as an argument costs a temporary
         do k = 1, 3
            values(k) = self%u(mesh%triangles(k, t), alpha)
         end do
         grad(:, alpha) = matmul(hat, values)
      end do
   end subroutine gradients_on

   !> r(:, α) = the values of the residual lifting r_α at the three vertices of triangle t.
   pure subroutine lifting_on(self, mesh, t, r)
      type(evaluated_iterate_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp), intent(out) :: r(3, 2)

      if (t > self%nt_owned) then
         r = self%ghost_lift(:, :, t - self%nt_owned)
      else
         call lifting_on_triangle(mesh, self%shares, t, r)
      end if
   end subroutine lifting_on

   !> Whether triangle t is in full contact: u1h ≤ u2h at its three vertices, up to the round-off
   !> of the contact rows (a ghost triangle: as its owner found it, after `share_ghosts`).
   pure logical function in_contact(self, mesh, t)
      type(evaluated_iterate_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t

      integer :: k
      integer(ip) :: b

      if (t > self%nt_owned) then
         in_contact = self%ghost_contact(t - self%nt_owned)
         return
      end if
      in_contact = .true.
      do k = 1, 3
         b = mesh%triangles(k, t)
         if (self%u(b, 1) - self%u(b, 2) > gap_tolerance*(abs(self%u(b, 1)) + abs(self%u(b, 2)))) then
            in_contact = .false.
            return
         end if
      end do
   end function in_contact

   !> The residuals written into `shares` become their patch shares (before any lifting_on).
   subroutine set_shares(self, mesh)
      class(evaluated_iterate_t), intent(inout) :: self
      type(mesh_t), intent(in) :: mesh

      call patch_shares(mesh, self%shares)
   end subroutine set_shares

   !> The ghost triangles' ∇u_α, r_α and contact from their owners, once the nodal fields are set
   !> (level: the finest mesh's level in the hierarchy). Collective among neighbours; nothing on
   !> one rank.
   subroutine share_ghosts(self, ghosts, mesh, level)
      class(evaluated_iterate_t), intent(inout) :: self
      type(ghost_cells_t), intent(in) :: ghosts
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level

      integer(ip), allocatable :: sent(:)
      real(dp), allocatable :: values(:, :), tail(:, :)
      real(dp) :: grad(2, 2), r(3, 2)
      integer(ip) :: k, t

      if (.not. ghosts%has_neighbours()) return
      sent = ghosts%sent_triangles(level)
      allocate (values(11, size(sent)), tail(11, mesh%nt - mesh%nt_owned))
      !$omp parallel do default(none) shared(self, mesh, sent, values) private(k, t, grad, r) schedule(static)
      do k = 1, size(sent, kind=ip)
         t = sent(k)
         call gradients_on(self, mesh, t, p1_gradients(mesh, t), grad)
         call lifting_on(self, mesh, t, r)
         values(1:4, k) = reshape(grad, [4])
         values(5:10, k) = reshape(r, [6])
         values(11, k) = merge(1.0_dp, 0.0_dp, in_contact(self, mesh, t))
      end do
      !$omp end parallel do
      call ghosts%share(level, values, tail)
      self%ghost_grad = reshape(tail(1:4, :), shape(self%ghost_grad))
      self%ghost_lift = reshape(tail(5:10, :), shape(self%ghost_lift))
      self%ghost_contact = tail(11, :) > 0.5_dp
   end subroutine share_ghosts
end module twomem_estimate_evaluated_iterate
