!> The estimators' patch loops (src/fortran/estimate): the block colouring that lets patches add
!> into their triangles in parallel, the canonical order in which the patch tables store a
!> patch's triangles, and the stored patch signatures (the factored class path), whose fluxes
!> must equal those of every patch assembled and factorized on its own. The fixtures are
!> test_estimate's.
module test_patch_loops
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_disc_flux, only: discretization_flux, load_moments_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_alg_flux, only: algebraic_flux_t, level_flux_t
   use twomem_estimate_patch_classes, only: patch_table_t, patch_order, stored_order, no_code
   use twomem_estimate_generic_patch, only: generic_scratch_t
   use twomem_estimate_ghosts, only: ghost_cells_t
   use twomem_linalg_halo, only: halo_t
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   use test_estimate, only: mesh_problem, poly_data_t, path_fixtures, iterate_fields, random_vector
   implicit none
   private

   public :: collect_patch_loops

contains

   subroutine collect_patch_loops(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('block_colouring', test_block_colouring), &
               new_unittest('stored_patch_order', test_stored_order), &
               new_unittest('patch_signatures', test_signatures)]
   end subroutine collect_patch_loops

   !> The patch loops' block colouring: every vertex listed once, in one block; no two blocks of
   !> one colour share a triangle (no triangle has corners in two different blocks of one
   !> colour), so their patches can add into their triangles in parallel; and, on a mesh large
   !> enough for it, several blocks per colour (work for more than one thread). From a single
   !> coarse mesh (one block) to four red refinements of the disk.
   subroutine test_block_colouring(err)
      type(error_t), allocatable, intent(out) :: err

      type(poly_data_t) :: data
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t) :: p
      type(coloring_t) :: colors
      integer(ip), allocatable :: block_of(:), seen(:)
      integer, allocatable :: color_of(:)
      integer(ip) :: ib, m, t, a
      integer :: c, levels, i, j
      logical :: shared, many

      do levels = 0, 4, 2
         call mesh_problem('disk', 0.4_dp, levels, data, h, p, err)
         if (allocated(err)) return
         associate (mesh => h%meshes(levels))
            call colors%init(mesh)
            allocate (block_of(mesh%nv), color_of(size(colors%block_ptr) - 1), seen(mesh%nv))
            seen = 0
            block_of = 0
            many = .true.
            do c = 1, colors%n_colors
               many = many .and. colors%ptr(c + 1) - colors%ptr(c) >= 4
               do ib = colors%ptr(c), colors%ptr(c + 1) - 1
                  color_of(ib) = c
                  do m = colors%block_ptr(ib), colors%block_ptr(ib + 1) - 1
                     a = colors%vertices(m)
                     seen(a) = seen(a) + 1
                     block_of(a) = ib
                  end do
               end do
            end do
            call check(err, all(seen == 1), 'every vertex in exactly one block')
            if (allocated(err)) return
            shared = .false.
            do t = 1, mesh%nt
               do i = 1, 3
                  do j = i + 1, 3
                     associate (bi => block_of(mesh%triangles(i, t)), bj => block_of(mesh%triangles(j, t)))
                        shared = shared .or. (bi /= bj .and. color_of(bi) == color_of(bj))
                     end associate
                  end do
               end do
            end do
            call check(err, .not. shared, 'two blocks of one colour share a triangle')
            if (allocated(err)) return
            if (levels == 4) call check(err, many .and. colors%n_colors <= 12, 'several blocks per colour, few colours')
            if (allocated(err)) return
            deallocate (block_of, color_of, seen)
         end associate
      end do
   end subroutine test_block_colouring

   !> The canonical order of a patch's triangles as the patch tables store it (3 bits per
   !> position) is the order patch_order sorts, for every patch of the finest mesh (`single`) and
   !> of the coarse mesh of a refined level (`refined`), RT0 and RT1; it lists each patch triangle
   !> once; and the same order comes back for a patch without a stored code (a patch of more
   !> than 8 triangles), which is sorted on the spot. A disk refined twice.
   subroutine test_stored_order(err)
      type(error_t), allocatable, intent(out) :: err

      type(poly_data_t) :: data
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t) :: p
      type(rt_space_t) :: space
      type(patch_table_t) :: table
      !> not classified: the classes of red refinement
      type(shape_classes_t) :: shapes
      integer(ip) :: a, expected(64), got(64)
      integer :: order, level, n, coded, code, k
      logical :: refined

      call mesh_problem('disk', 0.4_dp, 2, data, h, p, err)
      if (allocated(err)) return
      do order = 0, 1
         call space%init(order)
         do level = 1, 2
            ! level 2: the finest mesh's own patches; level 1: its patches on their refinement
            refined = level == 1
            call table%init(refined, 2)
            call table%add_mesh(space, shapes, h%meshes(level), h%meshes(merge(2, level, refined)), level)
            coded = 0
            associate (mesh => h%meshes(level))
               do a = 1, mesh%nv
                  if (table%levels(level)%id(a) == 0) cycle
                  n = int(mesh%patch_ptr(a + 1) - mesh%patch_ptr(a))
                  code = table%levels(level)%order(a)
                  if (code /= no_code) coded = coded + 1
                  call patch_order(shapes, mesh, level, a, expected(1:n))
                  call stored_order(shapes, mesh, level, a, code, got(1:n))
                  call check(err, all(got(1:n) == expected(1:n)), 'stored order = patch_order')
                  if (allocated(err)) return
                  call stored_order(shapes, mesh, level, a, no_code, got(1:n))
                  call check(err, all(got(1:n) == expected(1:n)), 'no code: sorted on the spot')
                  if (allocated(err)) return
                  do k = 1, n
                     call check(err, count(got(1:n) == mesh%patch_triangles(mesh%patch_ptr(a) + k - 1)) == 1, &
                                'each patch triangle once')
                  end do
                  if (allocated(err)) return
               end do
            end associate
            call check(err, coded > 0, 'some patches coded')
            if (allocated(err)) return
            call table%free()
         end do
      end do
   end subroutine test_stored_order

   !> Both fluxes with the patch tables (factors shared by signature, boundary vertices' patches
   !> included, with their free edges on ∂Ω) equal the fluxes from every patch assembled and
   !> factorized on its own, to round-off: σ_disc on the finest mesh, σ_alg with three meshes
   !> (two refined levels, the first with the coarse Riesz representer), RT0 and RT1, on the
   !> disk and on the square (3 × 3 cells: two corners cut off by a triangle with two edges on
   !> ∂Ω, whose neighbours along ∂Ω have a triangle with its far edge on ∂Ω, and whose corner
   !> vertex has a single-triangle patch), refined twice.
   subroutine test_signatures(err)
      type(error_t), allocatable, intent(out) :: err
      !> the generic path's per-thread scratch, the one-rank halo and ghost layer
      type(generic_scratch_t), allocatable :: scratch(:)
      type(halo_t) :: halo
      type(ghost_cells_t) :: ghosts

      character(len=6), parameter :: domains(2) = ['disk  ', 'square']
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(rt_space_t) :: space
      type(algebraic_flux_t) :: alg
      type(shape_classes_t) :: shapes
      type(coloring_t) :: colors
      type(load_moments_t) :: loads
      type(patch_table_t) :: no_signatures, single, refined
      type(evaluated_iterate_t) :: iterate
      type(level_flux_t), allocatable :: general(:)
      real(dp), allocatable :: lambda(:), grad_u(:, :, :), residual(:, :), r(:, :, :), sigma(:, :, :), sigma_general(:, :, :)
      real(dp) :: mu(2)
      integer :: domain, order, j, n_boundary
      integer(ip) :: a
      logical :: ok
      character(len=40) :: what

      do domain = 1, 2
         call mesh_problem(trim(domains(domain)), merge(0.4_dp, 0.7_dp, domain == 1), 2, data, h, p, err)
         if (allocated(err)) return
         call path_fixtures(h, p, scratch, halo, ghosts)
         call iterate_fields(p, h%meshes(2), random_vector(3*p%n, 30 + domain), lambda, grad_u, residual, r, iterate)
         mu = [p%mu1, p%mu2]
         call colors%init(h%meshes(2))
         do order = 0, 1
            write (what, '("RT",i0,", ",a)') order, trim(domains(domain))
            call space%init(order)
            call shapes%init(space, h, err)
            if (allocated(err)) return
            call loads%init(space, h%meshes(2), data)
            call alg%init(space, h, data, 3, .true., huge(1_ip), 1.0_dp, err)
            if (allocated(err)) return
            call alg%take_residual(h, residual, p%interior)
            call alg%compute(shapes, h, iterate, no_signatures, no_signatures, scratch, p, halo, ghosts, err)
            if (allocated(err)) return
            general = alg%levels
            if (allocated(sigma)) deallocate (sigma, sigma_general)
            allocate (sigma(space%n_flux, h%meshes(2)%nt, 2), sigma_general(space%n_flux, h%meshes(2)%nt, 2))
            call discretization_flux(space, shapes, no_signatures, h%meshes(2), 2, colors, mu, loads, iterate, &
                                     scratch, sigma_general, ok)
            call check(err, ok, 'patch systems regular, '//trim(what))
            if (allocated(err)) return
            ! the tables as the estimators build them, counting the boundary patches they factor
            call single%init(.false., 2)
            call single%add_mesh(space, shapes, h%meshes(2), h%meshes(2), 2)
            call single%finish(space, shapes, err)
            if (allocated(err)) return
            n_boundary = count(h%meshes(2)%boundary_vertex .and. single%levels(2)%id > 0)
            call refined%init(.true., 2)
            do j = alg%first(), 2
               call refined%add_mesh(space, shapes, h%meshes(j - 1), h%meshes(j), j - 1)
               do a = 1, h%meshes(j - 1)%nv
                  if (h%meshes(j - 1)%boundary_vertex(a) .and. refined%levels(j - 1)%id(a) > 0) n_boundary = n_boundary + 1
               end do
            end do
            call refined%finish(space, shapes, err)
            if (allocated(err)) return
            call check(err, n_boundary > 0, 'boundary patches with signatures, '//trim(what))
            if (allocated(err)) return
            call discretization_flux(space, shapes, single, h%meshes(2), 2, colors, mu, loads, iterate, scratch, sigma, ok)
            call check(err, maxval(abs(sigma - sigma_general)) <= 1.0e-12_dp*maxval(abs(sigma_general)), &
                       'sigma_disc: signatures = general path, '//trim(what))
            if (allocated(err)) return
            call alg%take_residual(h, residual, p%interior)
            call alg%compute(shapes, h, iterate, single, refined, scratch, p, halo, ghosts, err)
            if (allocated(err)) return
            do j = 1, size(general)
               call check(err, maxval(abs(alg%levels(j)%sigma - general(j)%sigma)) <= &
                          1.0e-12_dp*maxval(abs(general(j)%sigma)), 'sigma_alg: signatures = general path, '//trim(what))
            end do
            if (allocated(err)) return
            call single%free()
            call refined%free()
         end do
      end do
   end subroutine test_signatures
end module test_patch_loops
