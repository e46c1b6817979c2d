!> The multigrid transfers a run's solves use: the prolongations of the refinement hierarchy,
!> each level's interface in a distributed run and the keys of the coarsest level's gathered
!> solve, built once and shared by every level's Newton; and below a mesh too large to be
!> solved directly, algebraic coarse levels by smoothed aggregation of its stiffness
!> (twomem_linalg_aggregation), so that multigrid costs O(n) on any mesh. Algebraic levels are
!> built on one rank; a distributed run gathers its coarsest mesh and solves it directly.
module twomem_app_transfers
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_comm, only: comm_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: stiffness_rows
   use twomem_fem_transfer, only: interior_prolongations, interior_numbering, interior_vertices, interior_halo
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_linalg_aggregation, only: aggregation_options_t, aggregation_levels
   implicit none
   private

   public :: hierarchy_transfer, mesh_transfer

contains

   !> The transfers of levels bottom..top of the hierarchy (top = bottom without multigrid), with
   !> algebraic levels below `bottom` when its mesh is too large for a direct solve: level l of
   !> the hierarchy is then level l − bottom + transfer%algebraic of the transfers. `p` is the
   !> finest problem, whose stiffness serves when bottom is the finest level. Collective.
   subroutine hierarchy_transfer(comm, hierarchy, bottom, p, multigrid, transfer, err)
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: bottom
      type(discrete_problem_t), intent(in) :: p
      logical, intent(in) :: multigrid
      type(multigrid_transfer_t), intent(inout) :: transfer
      type(error_t), allocatable, intent(out) :: err

      type(halo_t), allocatable :: halos(:)
      type(csr_t), allocatable :: prolongations(:), algebraic(:)
      type(csr_t) :: stiffness
      real(dp), allocatable :: coupling(:)
      integer(ip), allocatable :: unknown(:), interior(:), keys(:)
      integer :: l, top

      ! the multigrid preconditioner of every level uses the levels below it
      top = merge(hierarchy%levels, bottom, multigrid)
      allocate (halos(0:top - bottom))
      do l = bottom, top
         unknown = interior_numbering(hierarchy%meshes(l))
         interior = interior_vertices(unknown)
         call interior_halo(hierarchy%meshes(l), interior, comm, halos(l - bottom))
         if (l == bottom) keys = hierarchy%meshes(l)%global_vertex_of(interior)
      end do
      prolongations = interior_prolongations(hierarchy, top)
      if (multigrid .and. comm%size == 1 .and. needs_algebraic_levels(size(keys, kind=ip))) then
         if (bottom == hierarchy%levels) then
            call aggregation_levels(p%stiffness, aggregation_options_t(), algebraic, err)
         else
            call stiffness_rows(hierarchy%meshes(bottom), unknown_of(hierarchy, bottom), stiffness, coupling)
            call aggregation_levels(stiffness, aggregation_options_t(), algebraic, err)
         end if
         if (allocated(err)) return
      else
         allocate (algebraic(0))
      end if
      call with_algebraic_levels(algebraic, prolongations(bottom + 1:top), halos, keys, comm, transfer, err)
   end subroutine hierarchy_transfer

   !> The transfers of one mesh's problem p on one rank (a mesh with no hierarchy of its own):
   !> algebraic levels below it when it is too large for a direct solve and `multigrid`, else
   !> the one level, solved directly.
   subroutine mesh_transfer(p, multigrid, transfer, err)
      type(discrete_problem_t), intent(in) :: p
      logical, intent(in) :: multigrid
      type(multigrid_transfer_t), intent(inout) :: transfer
      type(error_t), allocatable, intent(out) :: err

      type(csr_t), allocatable :: algebraic(:)
      type(csr_t) :: none(0)
      integer(ip) :: i

      if (multigrid .and. needs_algebraic_levels(p%n)) then
         call aggregation_levels(p%stiffness, aggregation_options_t(), algebraic, err)
         if (allocated(err)) return
      else
         allocate (algebraic(0))
      end if
      call with_algebraic_levels(algebraic, none, [p%halo], [(i, i=1, p%n)], p%halo%comm, transfer, err)
   end subroutine mesh_transfer

   !> Whether a coarsest mesh of n unknowns gets algebraic levels below it (a direct solve of
   !> it would cost more than the V-cycle's other levels).
   pure logical function needs_algebraic_levels(n)
      integer(ip), intent(in) :: n

      type(aggregation_options_t) :: defaults

      needs_algebraic_levels = n > defaults%coarse_size
   end function needs_algebraic_levels

   !> The unknown numbering of hierarchy level l's mesh.
   function unknown_of(hierarchy, l) result(unknown)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: l
      integer(ip), allocatable :: unknown(:)

      unknown = interior_numbering(hierarchy%meshes(l))
   end function unknown_of

   !> transfer from the algebraic prolongations (coarsest first) below the nested ones, whose
   !> coarsest level has the interface halos(0) and the keys `keys`.
   subroutine with_algebraic_levels(algebraic, nested, halos, keys, comm, transfer, err)
      type(csr_t), intent(in) :: algebraic(:), nested(:)
      type(halo_t), intent(in) :: halos(0:)
      integer(ip), intent(in) :: keys(:)
      type(comm_t), intent(in) :: comm
      type(multigrid_transfer_t), intent(inout) :: transfer
      type(error_t), allocatable, intent(out) :: err

      type(halo_t), allocatable :: all_halos(:)
      integer(ip) :: i
      integer :: l, m

      m = size(algebraic)
      if (m == 0) then
         call transfer%init(nested, err, halos=halos, coarse_keys=keys)
         return
      end if
      allocate (all_halos(0:m + size(nested)))
      do l = 0, m - 1
         call all_halos(l)%init_whole(comm, algebraic(l + 1)%ncol)
      end do
      all_halos(m:) = halos
      call transfer%init([algebraic, nested], err, halos=all_halos, coarse_keys=[(i, i=1, algebraic(1)%ncol)], &
                         algebraic=m)
   end subroutine with_algebraic_levels
end module twomem_app_transfers
