!> What a mesh hierarchy stores for the estimators' patch problems (docs/method.md §5,
!> *Estimator cost*). Stored data pay off where they are shared: the operators of a shape class
!> serve every copy of a coarse triangle on the refined levels, a signature's factor every
!> patch of its shape. But they scale with the coarse mesh while the rest of a run scales with
!> the finest one, and a large coarse mesh refined a little shares little: a 1e4-triangle Gmsh
!> mesh refined three times stored 615 MB of them for 3.4e5 vertices (RT1), a single mesh one
!> class per triangle and one signature per patch. So the stored data are bounded, in three
!> tiers, and what is not stored goes the generic way (twomem_estimate_generic_patch).
module twomem_estimate_storage
   use twomem_base_kinds, only: dp
   use twomem_base_comm, only: comm_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   implicit none
   private

   public :: storage_tier, max_single_shapes

   !> what the hierarchy stores for the patch problems (storage_tier)
   integer, parameter, public :: tier_none = 0, tier_single = 1, tier_all = 2
   !> the stored patch data's budget: this many bytes per finest vertex, or this many bytes in
   !> all, whichever is more (a small problem keeps every class and signature)
   real(dp), parameter :: setup_per_vertex = 250.0_dp, setup_floor = 128.0_dp*2**20

contains

   !> What the hierarchy stores for the patch problems:
   !> tier_all, the shape classes with the multilevel algebraic flux's tables and every patch
   !> signature's factor, finest mesh and refined levels; tier_single, the classes without those
   !> tables and the finest mesh's signatures only, the algebraic flux being the one-level
   !> construction on the finest mesh; tier_none, nothing (every patch on the generic path).
   !> The first that fits the budget: max(setup_floor, setup_per_vertex per finest vertex),
   !> with the stored bytes estimated per coarse triangle (set-up data scale with the coarse
   !> mesh, the rest of a run with the finest). A single mesh stores its classes by shape
   !> (shape_classes_t%classify) when every rank found them within max_single_shapes: tier_single
   !> (there are no refined levels), else tier_none; `shapes` is this rank's count (0: gave up).
   integer function storage_tier(hierarchy, order, alg_meshes, comm, shapes) result(tier)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: order, alg_meshes, shapes
      type(comm_t), intent(in) :: comm

      real(dp) :: coarse, finest, budget, classes(2), single, refined

      tier = tier_none
      if (hierarchy%levels == 0) then
         if (comm%min_real(real(shapes, dp)) > 0) tier = tier_single
         return
      end if
      coarse = comm%sum(real(hierarchy%meshes(0)%nt_owned, dp))
      finest = comm%sum(real(count(hierarchy%meshes(hierarchy%levels)%in_subdomain()), dp))
      budget = max(setup_floor, setup_per_vertex*finest)
      ! per coarse triangle: two classes (as itself and reflected) without and with the
      ! multilevel tables, the signatures' factors on the finest mesh and on each refined level
      ! of the algebraic flux (measured on a 1e4-triangle Gmsh mesh refined three times)
      if (order == 1) then
         classes = [5.9e3_dp, 11.4e3_dp]*2
         single = 6.5e3_dp
         refined = 17.0e3_dp
      else
         classes = [2.0e3_dp, 5.0e3_dp]*2
         single = 3.0e3_dp
         refined = 5.5e3_dp
      end if
      refined = refined*max(0, min(alg_meshes - 1, hierarchy%levels))
      if (coarse*(classes(2) + single + refined) <= budget) then
         tier = tier_all
      else if (coarse*(classes(1) + single) <= budget) then
         tier = tier_single
      end if
   end function storage_tier

   !> The most shapes a single mesh may store (shape_classes_t%classify) within this rank's
   !> share of the budget: per shape its two classes (as itself and reflected) and the factors
   !> of the distinct patches it makes (about eight per shape on meshes adapted by
   !> newest-vertex bisection; measured with RT1 on the re-entrant corner's adaptive run).
   integer function max_single_shapes(mesh, order) result(n)
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: order

      real(dp) :: per_shape

      if (order == 1) then
         per_shape = 2*5.9e3_dp + 8*2.6e3_dp
      else
         per_shape = 2*2.0e3_dp + 8*1.2e3_dp
      end if
      n = int(min(real(mesh%nt, dp), max(setup_floor, setup_per_vertex*count(mesh%in_subdomain()))/per_shape))
   end function max_single_shapes
end module twomem_estimate_storage
