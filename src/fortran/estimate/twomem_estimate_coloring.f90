!> Vertex colourings for the patch loops: two vertices of one colour never share a triangle, so
!> the patches of one colour can add their contributions into the flux coefficients of their
!> triangles in parallel without races, with no per-patch copies of the result (the three
!> vertex contributions of a triangle used to be stored apart and added afterwards, 48 numbers
!> per triangle for RT1). The colours come from a greedy sweep in vertex order, so a result is
!> summed in the same order whatever the number of threads. On a rank's piece of a distributed
!> mesh only the vertices of its own triangles are listed: their patches are whole there (the
!> ghost layer), the others' are not and belong to other ranks. Inside a colour the vertices go
!> in the order of their first patch triangle: red refinement numbers triangles along its tree,
!> so consecutive patches then touch neighbouring memory (vertex order, which lists each level's
!> new vertices after the old ones, scattered them: the four evaluations of the default case at
!> 10^6 vertices took 11.9 s, 10.2 s in this order). That order changes no sum, since the
!> patches of one colour share no triangle.
module twomem_estimate_coloring
   use twomem_base_kinds, only: ip
   use twomem_mesh_triangulation, only: mesh_t
   implicit none
   private

   public :: coloring_t

   type :: coloring_t
      !> the vertices of colour c are vertices(ptr(c):ptr(c+1)-1)
      integer :: n_colors = 0
      integer(ip), allocatable :: ptr(:), vertices(:)
   contains
      procedure :: init
   end type coloring_t

contains

   subroutine init(self, mesh)
      class(coloring_t), intent(out) :: self
      type(mesh_t), intent(in) :: mesh

      integer, allocatable :: color(:)
      integer(ip), allocatable :: count(:)
      integer(ip) :: a, m, t
      integer :: i, c
      !> a vertex has at most two neighbours per triangle of its patch, so one more colour
      !> than that always suffices
      logical, allocatable :: used(:)
      logical, allocatable :: inside(:)

      allocate (color(mesh%nv), used(2*maxval(mesh%patch_ptr(2:) - mesh%patch_ptr(:mesh%nv)) + 1))
      self%n_colors = 0
      do a = 1, mesh%nv
         used = .false.
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            t = mesh%patch_triangles(m)
            do i = 1, 3
               if (mesh%triangles(i, t) < a) used(color(mesh%triangles(i, t))) = .true.
            end do
         end do
         c = findloc(used, .false., dim=1)
         color(a) = c
         self%n_colors = max(self%n_colors, c)
      end do
      inside = mesh%in_subdomain()
      allocate (count(self%n_colors + 1), self%ptr(self%n_colors + 1), self%vertices(sum(merge(1_ip, 0_ip, inside))))
      count = 0
      do a = 1, mesh%nv
         if (inside(a)) count(color(a) + 1) = count(color(a) + 1) + 1
      end do
      self%ptr(1) = 1
      do c = 1, self%n_colors
         self%ptr(c + 1) = self%ptr(c) + count(c + 1)
      end do
      count(1:self%n_colors) = self%ptr(1:self%n_colors)
      do t = 1, mesh%nt
         do i = 1, 3
            a = mesh%triangles(i, t)
            if (.not. inside(a) .or. mesh%patch_triangles(mesh%patch_ptr(a)) /= t) cycle
            self%vertices(count(color(a))) = a
            count(color(a)) = count(color(a)) + 1
         end do
      end do
   end subroutine init
end module twomem_estimate_coloring
