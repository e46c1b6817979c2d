!> The algebraic two-membrane problem on one mesh (docs/method.md §1): unknowns at interior vertices
!> only, S the P1 stiffness restricted to them, D = diag(|ω_a|/3), and the right-hand sides
!> F1 = (f1, ψ_a) − μ1 S_IB g (the lifting of u1 = g) and F2 = (f2, ψ_a). It also maps between
!> interior vectors and nodal fields on the whole mesh, boundary values included. On a rank's
!> piece of a distributed mesh the unknowns are the interior vertices of its own triangles; the
!> stiffness holds its own triangles' part (products are summed across ranks by `halo`), while
!> D, F1 and F2 are summed once here and hold full values.
module twomem_fem_discrete
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_base_comm, only: comm_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_assembly, only: stiffness_rows, lumped_mass, assemble_loads
   use twomem_fem_transfer, only: interior_numbering, interior_vertices, interior_halo
   implicit none
   private

   public :: discrete_problem_t

   type :: discrete_problem_t
      !> number of interior vertices (unknowns per field)
      integer(ip) :: n = 0
      !> interior(i) is the mesh vertex of unknown i; unknown(a) is 0 on the boundary
      integer(ip), allocatable :: interior(:), unknown(:)
      !> S restricted to interior vertices, unit coefficient
      type(csr_t) :: stiffness
      !> lumped mass |ω_a|/3 at interior vertices
      real(dp), allocatable :: mass(:)
      !> the right-hand sides with the Dirichlet lifting, [F1; F2] (the Newton system's first two
      !> block rows read them as one vector)
      real(dp), allocatable :: f(:)
      real(dp) :: mu1 = 1.0_dp, mu2 = 1.0_dp, g = 0.0_dp
      !> the unknowns shared with other ranks, and the ones this rank owns
      type(halo_t) :: halo
      !> whole-mesh vertex number of every unknown
      integer(ip), allocatable :: global(:)
   contains
      procedure :: init => discrete_init
      procedure :: to_nodal
      procedure :: free_stiffness
   end type discrete_problem_t

contains

   !> The problem on `mesh`, a whole mesh or, with `comm`, this rank's piece of a distributed one.
   subroutine discrete_init(self, mesh, data, err, comm)
      class(discrete_problem_t), intent(inout) :: self
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      type(error_t), allocatable, intent(out) :: err
      type(comm_t), intent(in), optional :: comm

      real(dp), allocatable :: d_full(:), f_full(:, :), coupling(:)
      type(comm_t) :: one_rank

      self%mu1 = data%mu1
      self%mu2 = data%mu2
      self%g = data%g
      self%unknown = interior_numbering(mesh)
      self%n = count(self%unknown > 0, kind=ip)
      if (self%n == 0) then
         call make_error(err, exit_bad_input, 'mesh', 'the mesh has no interior vertex: refine it')
         return
      end if
      self%interior = interior_vertices(self%unknown)
      self%global = mesh%global_vertex_of(self%interior)
      if (present(comm)) then
         call interior_halo(mesh, self%interior, comm, self%halo)
      else
         call self%halo%init_whole(one_rank, self%n)
      end if

      ! K on the interior vertices; its boundary columns carry the lifting of u1 = g into F1
      ! (u2 = 0 there, so F2 needs none)
      call stiffness_rows(mesh, self%unknown, self%stiffness, coupling)
      d_full = lumped_mass(mesh)
      f_full = assemble_loads(mesh, data)
      ! a user's load that is not finite somewhere is bad input, found here once for all its uses
      if (.not. all(ieee_is_finite(f_full))) then
         call locate_bad_load(mesh, data, err)
         return
      end if
      self%mass = d_full(self%interior)
      self%f = [f_full(self%interior, 1) - self%mu1*self%g*coupling, f_full(self%interior, 2)]
      call self%halo%add(self%mass)
      call self%halo%add(self%f(1:self%n))
      call self%halo%add(self%f(self%n + 1:))
   end subroutine discrete_init

   !> The first quadrature point of the load rule (triangle order) where a load is not finite.
   subroutine locate_bad_load(mesh, data, err)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      type(error_t), allocatable, intent(out) :: err

      type(quadrature_t) :: rule
      real(dp) :: x(2), f(2, 1)
      integer(ip) :: t
      integer :: q, alpha
      character(len=80) :: where

      rule = triangle_rule(5)
      do t = 1, mesh%nt_owned
         do q = 1, rule%n
            x = matmul(mesh%vertices(:, mesh%triangles(:, t)), rule%bary(:, q))
            call data%loads_at(reshape(x, [2, 1]), f)
            do alpha = 1, 2
               if (ieee_is_finite(f(alpha, 1))) cycle
               write (where, '("(",es23.16,", ",es23.16,")")') x
               call make_error(err, exit_bad_input, 'problem.f'//achar(48 + alpha), 'not finite at the quadrature '// &
                               'point (x, y) = '//trim(where)//': '//data%explain_load(alpha, x))
               return
            end do
         end do
      end do
      call make_error(err, exit_bad_input, 'problem', 'the load vector is not finite')
   end subroutine locate_bad_load

   !> Nodal field on the whole mesh from interior values and a boundary value.
   function to_nodal(self, x, boundary_value) result(u)
      class(discrete_problem_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(in) :: boundary_value
      real(dp) :: u(size(self%unknown))

      u = boundary_value
      u(self%interior) = x
   end function to_nodal

   !> The stiffness matrix goes (0.09 KiB per vertex), once no residual and no evaluation of
   !> the estimators is left (the result record); the rest, maps and loads, stays.
   subroutine free_stiffness(self)
      class(discrete_problem_t), intent(inout) :: self

      call self%stiffness%free()
   end subroutine free_stiffness
end module twomem_fem_discrete
