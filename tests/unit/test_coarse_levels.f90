!> Coarse levels for a mesh given without coarser meshes. Smoothed aggregation
!> (twomem_linalg_aggregation): every unknown with a strong connection lies in one aggregate,
!> the prolongation reproduces constants away from the Dirichlet boundary and, for the P1
!> stiffness (an M-matrix on these meshes), is non-negative; a V-cycle over the algebraic
!> levels contracts fast and its rate does not grow with the mesh; truncated at fixed unknowns
!> it never moves them, and a partial refresh of such a hierarchy has the bits of a whole one.
!> Mesh coarsening (twomem_mesh_coarsening): the coarse mesh is a valid triangulation of a
!> subset of the vertices, with the shape bound, the corners of a polygonal domain kept and its
!> area unchanged; the interpolation injects at kept vertices and reproduces linear functions;
!> the two halves coarsened side by side give the bits of one thread's coarsening.
module test_coarse_levels
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_generators, only: make_disk
   use twomem_mesh_gmsh, only: read_gmsh
   use twomem_mesh_coarsening, only: coarsen, vertex_interpolation_t
   use twomem_fem_problem, only: constant_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_aggregation, only: aggregation_options_t, aggregation_levels, aggregate
   use twomem_linalg_multigrid, only: multigrid_t, multigrid_options_t, multigrid_transfer_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close
   use omp_lib, only: omp_get_max_threads, omp_set_num_threads
   implicit none
   private

   public :: collect_coarse_levels

contains

   subroutine collect_coarse_levels(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('aggregates_cover_the_connected_unknowns', test_aggregates), &
               new_unittest('prolongation_keeps_constants_and_sign', test_prolongation), &
               new_unittest('algebraic_vcycle_contraction_is_mesh_independent', test_contraction), &
               new_unittest('algebraic_vcycle_never_moves_fixed_unknowns', test_fixed), &
               new_unittest('algebraic_partial_refresh_matches_whole', test_partial), &
               new_unittest('coarse_mesh_is_valid_and_keeps_the_domain', test_coarse_mesh), &
               new_unittest('interpolation_reproduces_linear_functions', test_interpolation), &
               new_unittest('coarsening_is_the_same_on_any_thread_count', test_thread_count)]
   end subroutine collect_coarse_levels

   !> The P1 problem of the built-in disk meshed with size h, no refinement.
   subroutine disk_problem(h, mesh, p, err)
      real(dp), intent(in) :: h
      type(mesh_t), intent(out) :: mesh
      type(discrete_problem_t), intent(out) :: p
      type(error_t), allocatable, intent(out) :: err

      type(constant_data_t) :: data

      call make_disk(h, h, mesh, err)
      if (allocated(err)) return
      call p%init(mesh, data, err)
   end subroutine disk_problem

   !> Transfers from the algebraic levels of p's stiffness (down to coarse_size unknowns).
   subroutine algebraic_transfer(p, coarse_size, transfer, err)
      type(discrete_problem_t), intent(in) :: p
      integer(ip), intent(in) :: coarse_size
      type(multigrid_transfer_t), intent(inout) :: transfer
      type(error_t), allocatable, intent(out) :: err

      type(csr_t), allocatable :: prolongations(:)
      type(halo_t), allocatable :: halos(:)
      type(aggregation_options_t) :: options
      integer(ip), allocatable :: keys(:)

      options%coarse_size = coarse_size
      call aggregation_levels(p%stiffness, p%halo, options, prolongations, halos, keys, err)
      if (allocated(err)) return
      call transfer%init(prolongations, err, halos=[halos, p%halo], coarse_keys=keys, algebraic=size(prolongations))
   end subroutine algebraic_transfer

   subroutine fill_random(state, v)
      integer(i8), intent(inout) :: state
      real(dp), intent(out) :: v(:)

      integer :: i

      do i = 1, size(v)
         state = mod(16807_i8*state, 2147483647_i8)
         v(i) = 2.0_dp*real(state, dp)/2147483647.0_dp - 1.0_dp
      end do
   end subroutine fill_random

   !> The energy-norm contraction of the V-cycle as an iteration x ← x + V(b − A x) on A x = 0
   !> from a random start, over 8 cycles (geometric mean of the last 4).
   real(dp) function contraction(mg, a, fixed) result(rate)
      type(multigrid_t), intent(inout) :: mg
      type(csr_t), intent(in) :: a
      logical, intent(in), optional :: fixed(:)

      real(dp), allocatable :: x(:), r(:), z(:), ax(:)
      real(dp) :: e(0:8)
      integer(i8) :: state
      integer :: k

      allocate (x(a%n), r(a%n), z(a%n), ax(a%n))
      state = 11_i8
      call fill_random(state, x)
      if (present(fixed)) x = merge(0.0_dp, x, fixed)
      do k = 0, 8
         call a%matvec(x, ax)
         e(k) = sqrt(dot_product(x, ax))
         if (k == 8) exit
         r = -ax
         call mg%vcycle(r, z)
         x = x + z
      end do
      rate = (e(8)/e(4))**0.25_dp
   end function contraction

   subroutine test_aggregates(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(discrete_problem_t) :: p
      integer(ip), allocatable :: agg(:)
      integer(ip) :: n_agg, c
      integer(ip), allocatable :: sizes(:)

      call disk_problem(0.05_dp, mesh, p, err)
      if (allocated(err)) return
      call aggregate(p%stiffness, 0.08_dp, agg, n_agg)
      call check(err, all(agg >= 1 .and. agg <= n_agg), 'every unknown of the Laplacian lies in an aggregate')
      allocate (sizes(n_agg))
      sizes = 0
      do c = 1, p%n
         sizes(agg(c)) = sizes(agg(c)) + 1
      end do
      call check(err, all(sizes >= 1), 'no aggregate is empty')
      ! a root and its neighbours: about seven unknowns in 2D
      call check(err, real(p%n, dp)/real(n_agg, dp) > 4.0_dp .and. real(p%n, dp)/real(n_agg, dp) < 12.0_dp, &
                 'aggregates hold a root and its neighbours')
   end subroutine test_aggregates

   subroutine test_prolongation(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(discrete_problem_t) :: p
      type(csr_t), allocatable :: pr(:)
      type(halo_t), allocatable :: halos(:)
      integer(ip), allocatable :: keys(:)
      type(aggregation_options_t) :: options
      real(dp), allocatable :: ones(:), sums(:), k_ones(:)
      integer(ip) :: i
      logical :: inner_ok

      call disk_problem(0.05_dp, mesh, p, err)
      if (allocated(err)) return
      options%coarse_size = 100
      call aggregation_levels(p%stiffness, p%halo, options, pr, halos, keys, err)
      if (allocated(err)) return
      call check(err, size(pr) >= 2, 'several algebraic levels down to 100 unknowns')
      associate (fine => pr(size(pr)))
         call check(err, fine%n == p%n, 'the last prolongation ends on the given operator')
         allocate (ones(fine%ncol), sums(fine%n), k_ones(p%n))
         ones = 1.0_dp
         call fine%matvec(ones, sums)
         ! rows whose stiffness row sums to zero (no Dirichlet neighbour) reproduce 1 exactly
         ones = 1.0_dp
         deallocate (ones)
         allocate (ones(p%n))
         ones = 1.0_dp
         call p%stiffness%matvec(ones, k_ones)
         inner_ok = .true.
         do i = 1, p%n
            if (abs(k_ones(i)) < 1.0e-12_dp) inner_ok = inner_ok .and. abs(sums(i) - 1.0_dp) < 1.0e-12_dp
         end do
         call check(err, inner_ok, 'P reproduces constants away from the boundary')
         call check(err, all(sums <= 1.0_dp + 1.0e-12_dp), 'row sums at most one')
         call check(err, all(fine%val >= -1.0e-14_dp), 'P is non-negative for the Laplacian (an M-matrix)')
      end associate
   end subroutine test_prolongation

   subroutine test_contraction(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: mg
      type(multigrid_options_t) :: options
      real(dp) :: rates(2), hs(2)
      integer :: k
      character(len=80) :: msg

      hs = [0.04_dp, 0.02_dp]
      do k = 1, 2
         call disk_problem(hs(k), mesh, p, err)
         if (allocated(err)) return
         call algebraic_transfer(p, 200_ip, transfer, err)
         if (allocated(err)) return
         call mg%init(p%stiffness, transfer, transfer%levels, options, .true., err)
         if (allocated(err)) return
         rates(k) = contraction(mg, p%stiffness)
      end do
      write (msg, '("rates ",2f7.4)') rates
      call check(err, all(rates < 0.45_dp), 'an algebraic V-cycle reduces the energy error at least twofold: '// &
                 trim(msg))
      call check(err, rates(2) < 1.2_dp*rates(1) + 0.02_dp, 'the rate does not grow with the mesh: '//trim(msg))
   end subroutine test_contraction

   !> A w-block-like hierarchy on algebraic levels: K cut at a fixed region, shifted elsewhere.
   subroutine test_fixed(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: mg
      type(multigrid_options_t) :: options
      logical, allocatable :: fixed(:)
      real(dp), allocatable :: shift(:), b(:), z(:)
      type(csr_t) :: a
      integer(i8) :: state
      integer(ip) :: i
      real(dp) :: rate
      character(len=40) :: msg

      call disk_problem(0.03_dp, mesh, p, err)
      if (allocated(err)) return
      call algebraic_transfer(p, 200_ip, transfer, err)
      if (allocated(err)) return
      allocate (fixed(p%n), shift(p%n), b(p%n), z(p%n))
      do i = 1, p%n
         fixed(i) = norm2(mesh%vertices(:, p%interior(i))) < 0.5_dp .or. mod(i, 13) == 0
         shift(i) = 0.01_dp*mod(i, 3)*p%mass(i)
      end do
      call mg%init(p%stiffness, transfer, transfer%levels, options, .false., err, base=p%stiffness)
      if (allocated(err)) return
      call mg%refresh(fixed, err, shift=shift)
      if (allocated(err)) return
      state = 5_i8
      call fill_random(state, b)
      b = merge(0.0_dp, b, fixed)
      call mg%vcycle(b, z)
      call check(err, all(merge(z, 0.0_dp, fixed) == 0.0_dp), 'fixed unknowns stay exactly zero')
      a = p%stiffness
      do i = 1, p%n
         if (fixed(i)) then
            where (a%col(a%row_ptr(i):a%row_ptr(i + 1) - 1) /= i) a%val(a%row_ptr(i):a%row_ptr(i + 1) - 1) = 0.0_dp
            a%val(a%find(i, i)) = 1.0_dp
         else
            a%val(a%find(i, i)) = a%val(a%find(i, i)) + shift(i)
         end if
      end do
      do i = 1, p%n
         if (fixed(i)) cycle
         where (fixed(a%col(a%row_ptr(i):a%row_ptr(i + 1) - 1))) a%val(a%row_ptr(i):a%row_ptr(i + 1) - 1) = 0.0_dp
      end do
      rate = contraction(mg, a, fixed)
      write (msg, '("rate ",f7.4)') rate
      call check(err, rate < 0.5_dp, 'the truncated algebraic hierarchy still converges fast: '//trim(msg))
   end subroutine test_fixed

   !> A hierarchy refreshed step by step (only the rows the flipped flags reach) holds the bits
   !> of one built whole for the last fixed set.
   subroutine test_partial(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: updated, whole
      type(multigrid_options_t) :: options
      logical, allocatable :: fixed(:), no_change(:)
      real(dp), allocatable :: shift(:)
      real(dp), parameter :: radii(4) = [0.3_dp, 0.5_dp, 0.45_dp, 0.2_dp]
      integer :: step, l
      integer(ip) :: i
      logical :: identical

      call disk_problem(0.03_dp, mesh, p, err)
      if (allocated(err)) return
      call algebraic_transfer(p, 200_ip, transfer, err)
      if (allocated(err)) return
      allocate (fixed(p%n), shift(p%n), no_change(p%n))
      shift = 0.0_dp
      no_change = .false.
      call updated%init(p%stiffness, transfer, transfer%levels, options, .false., err, base=p%stiffness)
      if (allocated(err)) return
      do step = 1, 4
         ! a contact disk that grows, then shrinks (flags flip both ways)
         do i = 1, p%n
            fixed(i) = norm2(mesh%vertices(:, p%interior(i))) < radii(step)
         end do
         if (step == 1) then
            call updated%refresh(fixed, err, shift=shift)
         else
            call updated%refresh(fixed, err, changed=no_change, shift=shift)
         end if
         if (allocated(err)) return
      end do
      call whole%init(p%stiffness, transfer, transfer%levels, options, .false., err, base=p%stiffness)
      if (allocated(err)) return
      call whole%refresh(fixed, err, shift=shift)
      if (allocated(err)) return
      identical = .true.
      do l = 0, transfer%levels - 1
         identical = identical .and. all(updated%levels(l)%a%val == whole%levels(l)%a%val)
      end do
      call check(err, identical, 'the partial refreshes end with the bits of a whole refresh')
   end subroutine test_partial

   !> The Gmsh L-shape (a re-entrant corner) coarsened twice.
   subroutine lshape_levels(fine, coarse, interpolation, err)
      type(mesh_t), intent(out) :: fine, coarse(2)
      type(vertex_interpolation_t), intent(out) :: interpolation(2)
      type(error_t), allocatable, intent(out) :: err

      character(len=512) :: root
      integer :: length, status

      call get_environment_variable('TWOMEM_TEST_DATA', root, length, status)
      call check(err, status == 0, 'TWOMEM_TEST_DATA is not set (run through ctest)')
      if (allocated(err)) return
      call read_gmsh(trim(root)//'/../../input/meshes/lshape.msh', fine, err)
      if (allocated(err)) return
      call coarsen(fine, 0.25_dp, coarse(1), interpolation(1), err)
      if (allocated(err)) return
      call coarsen(coarse(1), 0.25_dp, coarse(2), interpolation(2), err)
   end subroutine lshape_levels

   subroutine test_coarse_mesh(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: fine, coarse(2)
      type(vertex_interpolation_t) :: interpolation(2)
      real(dp), parameter :: corners(2, 6) = reshape([-1, -1, 0, -1, 0, 0, 1, 0, 1, 1, -1, 1], [2, 6])
      real(dp) :: q, worst
      integer(ip) :: t
      integer :: k, j
      logical :: subset, kept

      call lshape_levels(fine, coarse, interpolation, err)
      if (allocated(err)) return
      call check(err, coarse(1)%nv < fine%nv/3 .and. coarse(2)%nv < coarse(1)%nv/3, &
                 'each coarsening keeps about a quarter of the vertices')
      do j = 1, 2
         associate (c => coarse(j))
            call check_close(err, c%total_area(), 3.0_dp, 1.0e-12_dp, 0.0_dp, 'the L-shape keeps its area')
            call check(err, c%n_flipped == 0, 'every coarse triangle is counter-clockwise')
            worst = 1.0_dp
            do t = 1, c%nt
               associate (p => c%vertices(:, c%triangles(:, t)))
                  q = 4*sqrt(3.0_dp)*c%area(t)/(sum((p(:, 2) - p(:, 1))**2) + sum((p(:, 3) - p(:, 2))**2) + &
                                               sum((p(:, 1) - p(:, 3))**2))
               end associate
               worst = min(worst, q)
            end do
            call check(err, worst >= 0.15_dp - 1.0e-12_dp, 'every coarse triangle keeps the shape bound')
            do k = 1, 6
               kept = any(all(abs(c%vertices - spread(corners(:, k), 2, c%nv)) < 1.0e-12_dp, dim=1))
               call check(err, kept, 'the corners of the L-shape (the re-entrant one too) are kept')
            end do
         end associate
      end do
      subset = .true.
      do t = 1, coarse(1)%nv
         subset = subset .and. any(all(abs(fine%vertices - spread(coarse(1)%vertices(:, t), 2, fine%nv)) == 0.0_dp, &
                                       dim=1))
      end do
      call check(err, subset, 'the coarse vertices are fine vertices')
   end subroutine test_coarse_mesh

   subroutine test_interpolation(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: fine, coarse(2)
      type(vertex_interpolation_t) :: interpolation(2)
      real(dp), allocatable :: u(:)
      integer :: d
      integer(ip) :: i, injected

      call lshape_levels(fine, coarse, interpolation, err)
      if (allocated(err)) return
      allocate (u(fine%nv))
      ! the L-shape is a polygon whose corners are kept: every fine vertex lies in the coarse
      ! domain, so x and y interpolate exactly
      do d = 1, 2
         call interpolation(1)%apply(coarse(1)%vertices(d, :), u)
         call check(err, maxval(abs(u - fine%vertices(d, :))) < 1.0e-12_dp, 'P1 interpolation reproduces x and y')
      end do
      injected = 0
      do i = 1, fine%nv
         if (interpolation(1)%weight(1, i) == 1.0_dp) injected = injected + 1
      end do
      call check(err, injected == coarse(1)%nv, 'a kept vertex reads its own value')
      call check(err, all(abs(sum(interpolation(2)%weight, dim=1) - 1.0_dp) < 1.0e-14_dp), 'weights sum to one')
      call check(err, all(interpolation(2)%weight >= 0.0_dp), 'weights are non-negative')
   end subroutine test_interpolation
   !> The built-in disk (3.6·10^4 vertices) coarsened on one thread and on two, where the two
   !> halves of the vertices go side by side: the same coarse meshes and interpolation, bit for
   !> bit, and a valid mesh of the same polygon.
   subroutine test_thread_count(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: fine, coarse(2)
      type(vertex_interpolation_t) :: interpolation(2)
      integer :: threads, run

      call make_disk(0.01_dp, 0.01_dp, fine, err)
      if (allocated(err)) return
      threads = omp_get_max_threads()
      do run = 1, 2
         call omp_set_num_threads(run)
         call coarsen(fine, 0.25_dp, coarse(run), interpolation(run), err)
         if (allocated(err)) exit
      end do
      call omp_set_num_threads(threads)
      if (allocated(err)) return
      call check(err, coarse(1)%nv < fine%nv/3 .and. coarse(1)%nv > fine%nv/10, 'about a quarter of the vertices kept')
      call check(err, coarse(1)%nv == coarse(2)%nv .and. coarse(1)%nt == coarse(2)%nt, 'the same sizes')
      if (allocated(err)) return
      call check(err, all(coarse(1)%vertices == coarse(2)%vertices) .and. all(coarse(1)%triangles == coarse(2)%triangles), &
                 'the same coarse mesh on one and two threads')
      call check(err, all(interpolation(1)%vertex == interpolation(2)%vertex) .and. &
                 all(interpolation(1)%weight == interpolation(2)%weight), 'the same interpolation')
      call check_close(err, coarse(2)%total_area(), fine%total_area(), 1.0e-2_dp, 0.0_dp, &
                       'the coarse mesh covers the disk polygon (its boundary loses vertices)')
      call check(err, coarse(2)%n_flipped == 0, 'every coarse triangle is counter-clockwise')
   end subroutine test_thread_count
end module test_coarse_levels
