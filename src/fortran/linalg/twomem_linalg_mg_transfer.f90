!> The transfers of a multigrid hierarchy (twomem_linalg_multigrid): the prolongations between
!> consecutive levels and their transposes, where each coarse unknown of a nested level sits on
!> the finer one (its injection), every level's interface in a distributed run, and the keys of
!> the coarsest level's unknowns for its gathered solve. Built once per hierarchy and shared by
!> every multigrid on it (the Newton system's two SPD blocks, the estimators' Riesz problem).
module twomem_linalg_mg_transfer
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_comm, only: comm_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   implicit none
   private

   public :: multigrid_transfer_t

   type :: index_list_t
      integer(ip), allocatable :: i(:)
   end type index_list_t

   !> The prolongations of a hierarchy with levels 0..levels: p(l) from level l−1 to level l
   !> (rows of level l), r(l) = p(l)ᵀ, and injection(l)%i(j), the unknown of level l that coarse
   !> unknown j of level l−1 is (nested hierarchies keep every coarse vertex); the interface of
   !> every level's unknowns, and a global key of every unknown of level 0 for its gathered solve.
   !> The lowest `algebraic` levels' prolongations come from aggregation
   !> (twomem_linalg_aggregation): no coarse unknown sits at a fine one, so they have no
   !> injection, and level `algebraic` is the coarsest mesh.
   type :: multigrid_transfer_t
      integer :: levels = 0
      integer :: algebraic = 0
      type(csr_t), allocatable :: p(:), r(:)
      type(index_list_t), allocatable :: injection(:)
      type(halo_t), allocatable :: halos(:)
      integer(ip), allocatable :: coarse_keys(:)
   contains
      procedure :: init => transfer_init
      procedure :: drop_restrictions
      procedure :: restore_restrictions
   end type multigrid_transfer_t

contains

   !> R = Pᵀ goes (about 0.03 KiB per vertex) while no multigrid uses the transfers, as when a
   !> preconditioner is released for an evaluation of the estimators; `restore_restrictions`
   !> (which multigrid_t%init calls) transposes P again, to the same bits.
   subroutine drop_restrictions(self)
      class(multigrid_transfer_t), intent(inout) :: self

      if (allocated(self%r)) deallocate (self%r)
   end subroutine drop_restrictions

   subroutine restore_restrictions(self)
      class(multigrid_transfer_t), intent(inout) :: self

      integer :: l

      if (allocated(self%r) .or. .not. allocated(self%p)) return
      allocate (self%r(self%levels))
      do l = 1, self%levels
         self%r(l) = self%p(l)%transposed()
      end do
   end subroutine restore_restrictions

   !> From prolongations(l), l = 1..L, level l−1 to level l, the first `algebraic` of them (0 by
   !> default) from aggregation, the others nested. `halos` (levels 0..L) and `coarse_keys`
   !> describe a distributed hierarchy; without them the levels are whole (one rank, unknowns
   !> numbered 1..n). A hierarchy of one level needs `n_coarsest`.
   subroutine transfer_init(self, prolongations, err, halos, coarse_keys, n_coarsest, algebraic)
      class(multigrid_transfer_t), intent(inout) :: self
      type(csr_t), intent(in) :: prolongations(:)
      type(error_t), allocatable, intent(out) :: err
      type(halo_t), intent(in), optional :: halos(0:)
      integer(ip), intent(in), optional :: coarse_keys(:)
      integer(ip), intent(in), optional :: n_coarsest
      integer, intent(in), optional :: algebraic

      type(comm_t) :: one_rank
      integer :: l
      integer(ip) :: i, n0

      self%levels = size(prolongations)
      self%algebraic = 0
      if (present(algebraic)) self%algebraic = algebraic
      self%p = prolongations
      if (allocated(self%r)) deallocate (self%r, self%injection)
      if (allocated(self%halos)) deallocate (self%halos)
      allocate (self%r(self%levels), self%injection(self%levels))
      do l = 1, self%levels
         self%r(l) = self%p(l)%transposed()
         if (l > self%algebraic) then
            call find_injection(self%p(l), self%injection(l)%i, err)
            if (allocated(err)) return
         end if
         if (l > 1) then
            if (self%p(l)%ncol /= self%p(l - 1)%n) then
               call make_error(err, exit_io, 'multigrid', 'consecutive prolongations do not match')
               return
            end if
         end if
      end do
      if (present(halos)) then
         allocate (self%halos(0:self%levels), source=halos)
         self%coarse_keys = coarse_keys
      else
         n0 = 0
         if (present(n_coarsest)) n0 = n_coarsest
         if (self%levels > 0) n0 = self%p(1)%ncol
         allocate (self%halos(0:self%levels))
         call self%halos(0)%init_whole(one_rank, n0)
         do l = 1, self%levels
            call self%halos(l)%init_whole(one_rank, self%p(l)%n)
         end do
         self%coarse_keys = [(i, i=1, n0)]
      end if
   end subroutine transfer_init

   !> Coarse unknown j sits where fine row i of P has the single entry P(i, j) = 1. Missing one
   !> means P is not a nested prolongation.
   subroutine find_injection(p, injection, err)
      type(csr_t), intent(in) :: p
      integer(ip), allocatable, intent(out) :: injection(:)
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: i, k

      allocate (injection(p%ncol))
      injection = 0
      do i = 1, p%n
         k = p%row_ptr(i)
         if (p%row_ptr(i + 1) - k == 1) then
            if (p%val(k) == 1.0_dp) injection(p%col(k)) = i
         end if
      end do
      if (any(injection == 0)) call make_error(err, exit_io, 'multigrid', &
                                               'a coarse unknown has no fine counterpart (the hierarchy is not nested)')
   end subroutine find_injection
end module twomem_linalg_mg_transfer
