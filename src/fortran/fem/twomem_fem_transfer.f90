!> Transfer between consecutive levels of the nested hierarchy, restricted to the unknowns of
!> the discrete problem (interior vertices, numbered in vertex order). The prolongation P_l maps
!> a P1 function of level l−1 that vanishes on ∂Ω to level l exactly: an inherited vertex
!> copies its value, a new vertex (an edge midpoint) takes the mean of the edge's ends, and
!> boundary ends contribute zero. These matrices are all the multigrid preconditioner knows of
!> the geometry.
module twomem_fem_transfer
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_linalg_csr, only: csr_t
   implicit none
   private

   public :: interior_numbering, interior_prolongation, interior_prolongations

contains

   !> unknown(a): the number of vertex a among the interior vertices (in vertex order), 0 on ∂Ω.
   pure function interior_numbering(mesh) result(unknown)
      type(mesh_t), intent(in) :: mesh
      integer(ip), allocatable :: unknown(:)

      integer(ip) :: a, n

      allocate (unknown(mesh%nv))
      n = 0
      do a = 1, mesh%nv
         if (mesh%boundary_vertex(a)) then
            unknown(a) = 0
         else
            n = n + 1
            unknown(a) = n
         end if
      end do
   end function interior_numbering

   !> P_l from level l−1 to level l of `hierarchy` (l ≥ 1), on interior unknowns.
   function interior_prolongation(hierarchy, l) result(p)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: l
      type(csr_t) :: p

      integer(ip), allocatable :: fine(:), coarse(:), row_ptr(:), col(:)
      real(dp), allocatable :: val(:)
      integer(ip) :: a, k, nf, nnz, m

      ! allocated first: assigning the result to an unallocated array trips gfortran 12's
      ! -Wuninitialized at -O0
      allocate (fine(hierarchy%meshes(l)%nv), coarse(hierarchy%meshes(l - 1)%nv))
      fine(:) = interior_numbering(hierarchy%meshes(l))
      coarse(:) = interior_numbering(hierarchy%meshes(l - 1))
      nf = maxval(fine)
      allocate (row_ptr(nf + 1), col(2*nf), val(2*nf))
      row_ptr(1) = 1
      nnz = 0
      associate (parents => hierarchy%maps(l)%vertex_parents)
         do a = 1, hierarchy%meshes(l)%nv
            if (fine(a) == 0) cycle
            if (parents(1, a) == parents(2, a)) then
               nnz = nnz + 1
               col(nnz) = coarse(parents(1, a))
               val(nnz) = 1.0_dp
            else
               do k = 1, 2
                  m = coarse(parents(k, a))
                  if (m == 0) cycle
                  nnz = nnz + 1
                  col(nnz) = m
                  val(nnz) = 0.5_dp
               end do
            end if
            row_ptr(fine(a) + 1) = nnz + 1
         end do
      end associate
      call p%init_pattern(row_ptr, col(1:nnz), ncol=maxval(coarse))
      ! sorting may swap the two entries of a midpoint row, which are equal: values keep their place
      p%val = val(1:nnz)
   end function interior_prolongation

   !> P_1 .. P_L for levels 0..L of `hierarchy` (L = `finest`).
   function interior_prolongations(hierarchy, finest) result(p)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: finest
      type(csr_t), allocatable :: p(:)

      integer :: l

      allocate (p(finest))
      do l = 1, finest
         p(l) = interior_prolongation(hierarchy, l)
      end do
   end function interior_prolongations
end module twomem_fem_transfer
