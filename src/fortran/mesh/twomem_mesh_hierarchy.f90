!> The nested hierarchy T_0 ⊂ T_1 ⊂ … ⊂ T_L made by uniform red refinement. Each refinement
!> keeps the coarse vertices first and in order, then adds one vertex per coarse edge at its
!> midpoint, and splits each triangle into four children numbered 4(t-1)+1..4t. Boundary
!> midpoints stay on the boundary chord, so the meshes are geometrically nested: a coarse P1
!> function is exactly representable on every finer level, which nested iteration and the
!> multilevel algebraic flux rely on. Prolongation is therefore just midpoint averaging.
module twomem_mesh_hierarchy
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t
   implicit none
   private

   public :: mesh_hierarchy_t, refinement_map_t, refine_red

   !> How level l was made from level l-1.
   type :: refinement_map_t
      !> the two coarse vertices whose mean is fine vertex a (equal for an inherited vertex),
      !> (2, nv_fine)
      integer(ip), allocatable :: vertex_parents(:, :)
      !> the coarse triangle each fine triangle lies in, (nt_fine)
      integer(ip), allocatable :: triangle_parent(:)
   end type refinement_map_t

   type :: mesh_hierarchy_t
      integer :: levels = 0
      !> meshes(0) is the coarse mesh, meshes(levels) the finest
      type(mesh_t), allocatable :: meshes(:)
      !> maps(l) relates level l to level l-1, l = 1..levels
      type(refinement_map_t), allocatable :: maps(:)
   contains
      procedure :: init => hierarchy_init
      procedure :: free => hierarchy_free
      procedure :: prolong
   end type mesh_hierarchy_t

contains

   !> Refine `coarse` `levels` times; the coarse mesh is copied into level 0.
   subroutine hierarchy_init(self, coarse, levels, err)
      class(mesh_hierarchy_t), intent(inout) :: self
      type(mesh_t), intent(in) :: coarse
      integer, intent(in) :: levels
      type(error_t), allocatable, intent(out) :: err

      integer :: l

      call self%free()
      self%levels = levels
      allocate (self%meshes(0:levels), self%maps(levels))
      self%meshes(0) = coarse
      do l = 1, levels
         call refine_red(self%meshes(l - 1), self%meshes(l), self%maps(l), err)
         if (allocated(err)) return
      end do
   end subroutine hierarchy_init

   subroutine hierarchy_free(self)
      class(mesh_hierarchy_t), intent(inout) :: self

      if (allocated(self%meshes)) deallocate (self%meshes)
      if (allocated(self%maps)) deallocate (self%maps)
      self%levels = 0
   end subroutine hierarchy_free

   !> Interpolate nodal values of a P1 function from level l-1 to level l (exact, since the
   !> spaces are nested).
   subroutine prolong(self, level, coarse_values, fine_values)
      class(mesh_hierarchy_t), intent(in) :: self
      integer, intent(in) :: level
      real(dp), intent(in) :: coarse_values(:)
      real(dp), intent(out) :: fine_values(:)

      integer(ip) :: a

      associate (p => self%maps(level)%vertex_parents)
         do a = 1, size(fine_values, kind=ip)
            fine_values(a) = 0.5_dp*(coarse_values(p(1, a)) + coarse_values(p(2, a)))
         end do
      end associate
   end subroutine prolong

   subroutine refine_red(coarse, fine, map, err)
      type(mesh_t), intent(in) :: coarse
      type(mesh_t), intent(inout) :: fine
      type(refinement_map_t), intent(out) :: map
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      integer(ip) :: nv, a, e, t, m(3), v(3)

      nv = coarse%nv + coarse%ne
      allocate (vertices(2, nv), triangles(3, 4*coarse%nt))
      allocate (map%vertex_parents(2, nv), map%triangle_parent(4*coarse%nt))
      do a = 1, coarse%nv
         vertices(:, a) = coarse%vertices(:, a)
         map%vertex_parents(:, a) = a
      end do
      do e = 1, coarse%ne
         associate (ends => coarse%edges(:, e))
            vertices(:, coarse%nv + e) = 0.5_dp*(coarse%vertices(:, ends(1)) + coarse%vertices(:, ends(2)))
            map%vertex_parents(:, coarse%nv + e) = ends
         end associate
      end do
      do t = 1, coarse%nt
         v = coarse%triangles(:, t)
         ! m(i) is the midpoint of the edge opposite vertex i
         m = coarse%nv + coarse%triangle_edges(:, t)
         triangles(:, 4*t - 3) = [v(1), m(3), m(2)]
         triangles(:, 4*t - 2) = [m(3), v(2), m(1)]
         triangles(:, 4*t - 1) = [m(2), m(1), v(3)]
         triangles(:, 4*t) = [m(1), m(2), m(3)]
         map%triangle_parent(4*t - 3:4*t) = t
      end do
      call fine%init(vertices, triangles, 'red refinement', err, diameter=coarse%diameter)
   end subroutine refine_red
end module twomem_mesh_hierarchy
