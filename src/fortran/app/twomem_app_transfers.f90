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
      type(csr_t), allocatable :: prolongations(:)
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
      if (multigrid .and. needs_algebraic_levels(comm%sum(int(halos(0)%n_owned())))) then
         if (bottom == hierarchy%levels) then
            call algebraic_levels(p%stiffness, halos(0), prolongations(bottom + 1:top), halos, keys, transfer, err)
         else
            call stiffness_rows(hierarchy%meshes(bottom), unknown_of(hierarchy, bottom), stiffness, coupling)
            call algebraic_levels(stiffness, halos(0), prolongations(bottom + 1:top), halos, keys, transfer, err)
         end if
      else
         call transfer%init(prolongations(bottom + 1:top), err, halos=halos, coarse_keys=keys)
      end if
   end subroutine hierarchy_transfer

   !> The transfers of one mesh's problem p (a mesh with no hierarchy of its own): algebraic
   !> levels below it when it is too large for a direct solve and `multigrid`, else the one
   !> level, solved directly. Collective.
   subroutine mesh_transfer(p, multigrid, transfer, err)
      type(discrete_problem_t), intent(in) :: p
      logical, intent(in) :: multigrid
      type(multigrid_transfer_t), intent(inout) :: transfer
      type(error_t), allocatable, intent(out) :: err

      type(csr_t) :: none(0)

      if (multigrid .and. needs_algebraic_levels(p%halo%comm%sum(int(p%halo%n_owned())))) then
         call algebraic_levels(p%stiffness, p%halo, none, [p%halo], p%global, transfer, err)
      else
         call transfer%init(none, err, halos=[p%halo], coarse_keys=p%global)
      end if
   end subroutine mesh_transfer

   !> Whether a coarsest mesh of n unknowns gets algebraic levels below it (a direct solve of
   !> it would cost more than the V-cycle's other levels).
   pure logical function needs_algebraic_levels(n)
      integer, intent(in) :: n

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

   !> transfer with the algebraic levels of operator `a` (this rank's part; `halo` the interface
   !> of its unknowns) below the nested prolongations, whose levels have the interfaces `halos`
   !> (halos(0): a's) and whose coarsest level the keys `keys`; only the nested levels when
   !> aggregation does not coarsen. Collective.
   subroutine algebraic_levels(a, halo, nested, halos, keys, transfer, err)
      type(csr_t), intent(in) :: a
      type(halo_t), intent(in) :: halo
      type(csr_t), intent(in) :: nested(:)
      type(halo_t), intent(in) :: halos(0:)
      integer(ip), intent(in) :: keys(:)
      type(multigrid_transfer_t), intent(inout) :: transfer
      type(error_t), allocatable, intent(out) :: err

      type(csr_t), allocatable :: algebraic(:)
      type(halo_t), allocatable :: algebraic_halos(:)
      integer(ip), allocatable :: coarse_keys(:)
      integer :: m

      call aggregation_levels(a, halo, aggregation_options_t(), algebraic, algebraic_halos, coarse_keys, err)
      if (allocated(err)) return
      m = size(algebraic)
      if (m == 0) then
         call transfer%init(nested, err, halos=halos, coarse_keys=keys)
      else
         call transfer%init([algebraic, nested], err, halos=[algebraic_halos, halos], coarse_keys=coarse_keys, &
                            algebraic=m)
      end if
   end subroutine algebraic_levels
end module twomem_app_transfers
