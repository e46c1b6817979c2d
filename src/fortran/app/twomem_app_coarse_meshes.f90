!> Nested iteration below a mesh that has no coarser mesh (a user's fine mesh given as it is, or
!> a large coarse mesh under a refinement hierarchy): the mesh is coarsened by vertex removal
!> (twomem_mesh_coarsening) to a sequence of coarser meshes, the problem is solved on the
!> coarsest from the paper's initial guess and on each finer one from the interpolated
!> solution, its contact set settled as nested iteration on a refined hierarchy does
!> (twomem_newton_settle), and the given mesh starts Newton from the last of them. A coarser
!> mesh's solution places the free boundary within a layer or two of the fine one's, so the
!> given mesh needs a few Newton steps instead of a step per layer of vertices between the cold
!> start and the free boundary. The coarse meshes are the discrete problem's own on a coarser
!> triangulation (loads, tensions and boundary values as given), so each level is a sound
!> approximation, unlike a Galerkin coarse space of aggregation, whose solution misses a fixed
!> share of the deflection at every mesh size. Only Newton's path changes: the solution is the
!> given mesh's. A distributed mesh is gathered whole on every rank, and every rank makes the
!> same coarse meshes and solves the same coarse problems on its own (one rank each, the same
!> operations in the same order), then takes the start at its own vertices: the coarse levels
!> cost no communication and give every rank count the same start.
module twomem_app_coarse_meshes
   use, intrinsic :: iso_fortran_env, only: output_unit
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: method_direct, precond_mg
   use twomem_base_timer, only: wall_time
   use twomem_base_text, only: fixed
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_coarsening, only: coarsen, vertex_interpolation_t
   use twomem_mesh_partition, only: share_mesh
   use twomem_io_gather, only: gather_plan_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_newton_solver, only: newton_options_t, newton_result_t, newton_solve
   use twomem_newton_settle, only: settle_contact
   use twomem_app_transfers, only: mesh_transfer
   implicit none
   private

   public :: coarse_work_t, coarsened_start, cold_start

   !> Work spent on the coarser levels of nested iteration.
   type :: coarse_work_t
      integer :: newton_iterations = 0, gmres_iterations = 0
   end type coarse_work_t

   !> a mesh with more vertices than this is coarsened for its start; the coarsest mesh made
   !> has about this many
   integer(ip), parameter :: coarsest_vertices = 1500
   !> each coarser mesh keeps about this fraction of the vertices (as red refinement's inverse)
   real(dp), parameter :: fraction = 0.25_dp
   !> The relative residual to which the coarsened meshes are solved (newton.tol, if looser). A
   !> coarse solution only starts the next mesh, whose interpolated start has a relative
   !> residual of 10^-3 or more (the two meshes' discrete solutions differ by that much), so
   !> solving it further changes nothing downstream. Beyond it, on the other hand, inexact
   !> Newton-min can flip a vertex whose two min arguments are both below GMRES's algebraic
   !> error from one side of the free boundary to the other at every step until the forcing has
   !> tightened to newton.tol: 36 Newton steps on the 2·10^5-vertex mesh coarsened from a
   !> 10^6-vertex Gmsh mesh, 14 at this tolerance, with the same three steps on the given mesh.
   !> Every rank solves the same coarse problems alone, so the start stays the same for every
   !> rank count (a refined hierarchy's coarser levels, which are distributed and converge in a
   !> few steps, keep newton.tol: there a partial solve would carry the partition's imprint).
   real(dp), parameter :: coarse_tol = 1.0e-6_dp

   type :: coarse_level_t
      type(mesh_t) :: mesh
      !> how the next finer mesh's vertices read this mesh's P1 functions
      type(vertex_interpolation_t) :: to_finer
   end type coarse_level_t

contains

   !> The paper's initial guess (g, 0, 0) for problem p.
   function cold_start(p) result(x0)
      type(discrete_problem_t), intent(in) :: p
      real(dp), allocatable :: x0(:)

      x0 = [spread(p%g, 1, p%n), spread(0.0_dp, 1, 2*p%n)]
   end function cold_start

   !> Newton's start x0 for problem p on `mesh` (this rank's piece): by nested iteration over
   !> coarsened meshes when the whole mesh is large enough, else the paper's guess. `quiet` are
   !> the options of the coarser levels' Newton. Collective.
   subroutine coarsened_start(mesh, data, p, quiet, comm, x0, work, err)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      type(discrete_problem_t), intent(in) :: p
      type(newton_options_t), intent(in) :: quiet
      type(comm_t), intent(in) :: comm
      real(dp), allocatable, intent(out) :: x0(:)
      type(coarse_work_t), intent(inout) :: work
      type(error_t), allocatable, intent(out) :: err

      type(coarse_level_t), allocatable :: levels(:)
      type(mesh_t) :: whole
      real(dp), allocatable :: nodal(:, :)
      integer(ip), allocatable :: at(:)
      integer :: j, m

      x0 = cold_start(p)
      if (mesh%nv_global <= 2*coarsest_vertices) return
      ! the coarse solution comes back at the vertices of the mesh coarsened, in its numbering:
      ! one rank coarsens its own piece, several ranks the gathered whole mesh
      at = p%interior
      if (comm%size == 1) then
         call coarse_meshes(mesh, levels)
      else
         call whole_mesh(comm, mesh, whole, err)
         if (allocated(err)) return
         call coarse_meshes(whole, levels)
         at = mesh%global_vertex_of(at)
      end if
      m = size(levels)
      if (m == 0) return
      do j = m, 1, -1
         call solve_level(levels, j, data, quiet, comm%is_root(), nodal, work, err)
         if (allocated(err)) return
      end do
      ! the given mesh's start from the finest coarse level's solution, at this rank's vertices
      x0 = [nodal(at, 1), nodal(at, 2), nodal(at, 3)]
      call settle_contact(p, x0)
   end subroutine coarsened_start

   !> The whole mesh of which `piece` is this rank's, on every rank. Collective.
   subroutine whole_mesh(comm, piece, whole, err)
      type(comm_t), intent(in) :: comm
      type(mesh_t), intent(in) :: piece
      type(mesh_t), intent(inout) :: whole
      type(error_t), allocatable, intent(out) :: err

      type(gather_plan_t) :: plan
      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)

      call plan%init(comm, piece)
      call plan%mesh_arrays(piece, vertices, triangles)
      if (comm%is_root()) call whole%init(vertices, triangles, 'the gathered mesh', err, diameter=piece%diameter)
      call comm%agree(err)
      if (allocated(err)) return
      call share_mesh(comm, whole, 'the gathered mesh', err)
   end subroutine whole_mesh

   !> levels(1..m): each a coarsening of the one before (levels(1) of `mesh`), down to about
   !> coarsest_vertices; none if the mesh does not coarsen (a coarsening that fails, which its
   !> checks prevent, only ends the sequence: the start is then the paper's from there).
   subroutine coarse_meshes(mesh, levels)
      type(mesh_t), intent(in) :: mesh
      type(coarse_level_t), allocatable, intent(out) :: levels(:)

      type(coarse_level_t), allocatable :: made(:)
      type(error_t), allocatable :: err
      integer :: m

      allocate (made(20))
      m = 0
      do while (m < size(made))
         if (m == 0) then
            call coarsen(mesh, fraction, made(1)%mesh, made(1)%to_finer, err)
         else
            if (made(m)%mesh%nv <= coarsest_vertices) exit
            call coarsen(made(m)%mesh, fraction, made(m + 1)%mesh, made(m + 1)%to_finer, err)
         end if
         if (allocated(err)) exit
         m = m + 1
         ! a mesh that hardly shrank is as coarse as its boundary allows
         if (m > 1) then
            if (made(m)%mesh%nv > (3*made(m - 1)%mesh%nv)/4) exit
         else
            if (made(m)%mesh%nv > (3*mesh%nv)/4) exit
         end if
      end do
      allocate (levels(m))
      levels(1:m) = made(1:m)
   end subroutine coarse_meshes

   !> Newton on coarse level j (to `coarse_tol`) from the interpolated solution of level j+1
   !> (from the paper's guess on the coarsest), then its nodal fields u1, u2, λ interpolated to
   !> the next finer mesh, replacing `nodal`.
   subroutine solve_level(levels, j, data, quiet, report, nodal, work, err)
      type(coarse_level_t), intent(in) :: levels(:)
      integer, intent(in) :: j
      class(problem_data_t), intent(in) :: data
      type(newton_options_t), intent(in) :: quiet
      logical, intent(in) :: report
      real(dp), allocatable, intent(inout) :: nodal(:, :)
      type(coarse_work_t), intent(inout) :: work
      type(error_t), allocatable, intent(out) :: err

      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(newton_result_t) :: step
      type(newton_options_t) :: options
      real(dp), allocatable :: x0(:), u(:, :)
      real(dp) :: t0
      integer :: k

      t0 = wall_time()
      options = quiet
      options%tol = max(quiet%tol, coarse_tol)
      call p%init(levels(j)%mesh, data, err)
      if (allocated(err)) return
      if (j == size(levels)) then
         x0 = cold_start(p)
      else
         x0 = [nodal(p%interior, 1), nodal(p%interior, 2), nodal(p%interior, 3)]
         call settle_contact(p, x0)
      end if
      call mesh_transfer(p, options%precond == precond_mg .and. options%linear /= method_direct, transfer, err)
      if (allocated(err)) return
      call newton_solve(p, options, x0, step, err, transfer=transfer, level=transfer%levels)
      if (allocated(err)) return
      work%newton_iterations = work%newton_iterations + step%iterations
      work%gmres_iterations = work%gmres_iterations + step%linear_iterations
      if (report) write (output_unit, '("nested: coarsened mesh ",i2," (",i0," vertices): ",i4," Newton steps, ",i6,&
         &" GMRES iterations (",a,"), ",a," s")') j, levels(j)%mesh%nv, step%iterations, step%linear_iterations, &
         step%status, fixed(wall_time() - t0, 2)
      allocate (u(levels(j)%mesh%nv, 3))
      u(:, 1) = p%to_nodal(step%x(1:p%n), data%g)
      u(:, 2) = p%to_nodal(step%x(p%n + 1:2*p%n), 0.0_dp)
      u(:, 3) = p%to_nodal(step%x(2*p%n + 1:), 0.0_dp)
      if (allocated(nodal)) deallocate (nodal)
      allocate (nodal(size(levels(j)%to_finer%vertex, 2), 3))
      do k = 1, 3
         call levels(j)%to_finer%apply(u(:, k), nodal(:, k))
      end do
   end subroutine solve_level
end module twomem_app_coarse_meshes
