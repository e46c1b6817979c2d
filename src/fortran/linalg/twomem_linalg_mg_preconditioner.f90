!> One multigrid V-cycle (twomem_linalg_multigrid) for a fixed SPD operator as a
!> `preconditioner_t`: what the conjugate gradients of the estimators' Riesz problem take for
!> the stiffness matrix K. The hierarchy is built once for the operator given to `init`, on the
!> levels of a `multigrid_transfer_t` up to `top` (nothing fixed: the Newton S-block's set-up),
!> and frozen: its operator never changes. It does not depend on which levels the transfer has:
!> one level is a direct solve (top = 0). `release` gives the hierarchy's memory back; the next
!> `apply` or `setup` builds it again from the same operator and transfer.
module twomem_linalg_mg_preconditioner
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: preconditioner_t
   use twomem_linalg_multigrid, only: multigrid_t, multigrid_options_t, multigrid_transfer_t
   implicit none
   private

   public :: mg_preconditioner_t

   type, extends(preconditioner_t) :: mg_preconditioner_t
      !> the operator and the transfers, kept alive and in place by the caller
      type(csr_t), pointer :: a => null()
      type(multigrid_transfer_t), pointer :: transfer => null()
      integer :: top = 0
      type(multigrid_options_t) :: options
      !> allocatable: gfortran 12 leaves a plain multigrid_t component's levels allocated when
      !> its owner is deallocated (twomem_newton_elimination)
      type(multigrid_t), allocatable :: mg
      !> a build failed: `apply` returns zero (the conjugate gradients then report a breakdown)
      logical :: failed = .false.
   contains
      procedure :: init
      procedure :: setup
      procedure :: apply
      procedure :: release
      procedure :: built
   end type mg_preconditioner_t

contains

   !> The V-cycle of operator a on levels 0..top of `transfer` (a is level top's operator).
   !> Collective.
   subroutine init(self, a, transfer, top, options, err)
      class(mg_preconditioner_t), intent(inout) :: self
      type(csr_t), target, intent(in) :: a
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      integer, intent(in) :: top
      type(multigrid_options_t), intent(in) :: options
      type(error_t), allocatable, intent(out) :: err

      call self%release()
      self%a => a
      self%transfer => transfer
      self%top = top
      self%options = options
      call build(self, err)
   end subroutine init

   !> The hierarchy again for the operator of `init`, whose values may have changed (a must be
   !> that operator: the hierarchy keeps a pointer to it, not to this argument). Collective.
   subroutine setup(self, a, err)
      class(mg_preconditioner_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      if (.not. associated(self%a)) then
         call make_error(err, exit_io, 'multigrid preconditioner', 'internal: setup before init')
         return
      end if
      if (a%n /= self%a%n) then
         call make_error(err, exit_io, 'multigrid preconditioner', 'internal: not the operator of init')
         return
      end if
      call self%release()
      call build(self, err)
   end subroutine setup

   subroutine build(self, err)
      type(mg_preconditioner_t), intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      allocate (self%mg)
      call self%mg%init(self%a, self%transfer, self%top, self%options, .true., err)
      self%failed = allocated(err)
      if (self%failed) then
         deallocate (self%mg)
         return
      end if
      ! the operator never changes: what only a refresh reads goes
      call self%mg%freeze()
   end subroutine build

   !> z = one V-cycle applied to r (built again first after `release`). Collective.
   subroutine apply(self, r, z)
      class(mg_preconditioner_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      type(error_t), allocatable :: err

      if (.not. allocated(self%mg) .and. associated(self%a) .and. .not. self%failed) call build(self, err)
      if (.not. allocated(self%mg)) then
         z = 0.0_dp
         return
      end if
      call self%mg%vcycle(r, z)
      if (self%mg%failed) self%failed = .true.
   end subroutine apply

   !> The hierarchy goes (its factorization, coarse operators, smoothers and cycle vectors); the
   !> operator and the transfers stay the caller's.
   subroutine release(self)
      class(mg_preconditioner_t), intent(inout) :: self

      if (allocated(self%mg)) then
         call self%mg%free()
         deallocate (self%mg)
      end if
   end subroutine release

   !> Whether the hierarchy is built (not released).
   logical function built(self)
      class(mg_preconditioner_t), intent(in) :: self

      built = allocated(self%mg)
   end function built
end module twomem_linalg_mg_preconditioner
