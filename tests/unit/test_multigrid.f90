!> Multigrid and the block-elimination preconditioner against independent computations: the Galerkin
!> product against dense Pᵀ A P (truncated at fixed unknowns) and, for the Laplacian, against the
!> stiffness matrix assembled on the coarse mesh; the V-cycle's contraction on the Poisson problem
!> at several mesh sizes; truncation (fixed unknowns never move); the elimination without coarsening
!> against UMFPACK on the assembled Newton matrix; the partial rebuild of the w-block hierarchy for
!> a new Newton step against a whole rebuild and against a plain full product; the hierarchy
!> assembled in one pass against pattern then values; the preconditioner released and rebuilt
!> against itself before the release and against one built for that step alone; and GMRES
!> iteration counts with the preconditioner for both C-functions as the mesh is refined.
module test_multigrid
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_galerkin, only: galerkin_pattern, galerkin_values, truncate_transfer
   use twomem_linalg_multigrid, only: multigrid_t, multigrid_options_t, multigrid_transfer_t
   use twomem_linalg_halo, only: halo_t
   use twomem_base_comm, only: comm_t
   use twomem_linalg_operators, only: euclidean_product_t
   use twomem_linalg_gmres, only: gmres_solve, gmres_options_t, gmres_monitor_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: constant_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_transfer, only: interior_prolongation, interior_prolongations
   use twomem_newton_system, only: newton_system_t, newton_operator_t
   use twomem_newton_elimination, only: elimination_preconditioner_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_refinement, only: square_hierarchy, square_problem
   implicit none
   private

   public :: collect_multigrid

contains

   subroutine collect_multigrid(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('galerkin_matches_dense_truncated_product', test_galerkin_dense), &
               new_unittest('galerkin_of_p1_laplacian_is_coarse_stiffness', test_galerkin_rediscretizes), &
               new_unittest('vcycle_contraction_is_mesh_independent', test_vcycle_contraction), &
               new_unittest('vcycle_never_moves_fixed_unknowns', test_vcycle_fixed), &
               new_unittest('elimination_without_coarsening_is_exact', test_elimination_exact), &
               new_unittest('partial_rebuild_matches_full_rebuild', test_partial_rebuild), &
               new_unittest('assembled_hierarchy_matches_refresh', test_assembled_hierarchy), &
               new_unittest('frozen_hierarchy_cycles_the_same', test_frozen_hierarchy), &
               new_unittest('released_preconditioner_rebuilds_the_same', test_release), &
               new_unittest('gmres_with_multigrid_iterations_bounded', test_gmres_iterations)]
   end subroutine collect_multigrid

   subroutine fill_random(state, v)
      integer(i8), intent(inout) :: state
      real(dp), intent(out) :: v(:)

      integer :: i

      do i = 1, size(v)
         state = mod(16807_i8*state, 2147483647_i8)
         v(i) = 2.0_dp*real(state, dp)/2147483647.0_dp - 1.0_dp
      end do
   end subroutine fill_random

   function dense(a) result(d)
      type(csr_t), intent(in) :: a
      real(dp), allocatable :: d(:, :)

      integer(ip) :: i, k

      allocate (d(a%n, a%ncol))
      d = 0.0_dp
      do i = 1, a%n
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            d(i, a%col(k)) = d(i, a%col(k)) + a%val(k)
         end do
      end do
   end function dense

   !> The square problem refined `levels` times (its unit-coefficient stiffness is what the
   !> callers use) and the prolongation from the level below.
   subroutine square_with_prolongation(levels, h, p, prolongation, err)
      integer, intent(in) :: levels
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), intent(out) :: p
      type(csr_t), intent(out) :: prolongation
      type(error_t), allocatable, intent(out) :: err

      call square_problem(levels, h, p, err)
      if (allocated(err)) return
      prolongation = interior_prolongation(h, levels)
   end subroutine square_with_prolongation

   !> a with rows and columns of `fixed` replaced by identity rows and zero columns.
   subroutine dirichlet_rows(a, fixed)
      type(csr_t), intent(inout) :: a
      logical, intent(in) :: fixed(:)

      integer(ip) :: i, k

      do i = 1, a%n
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (fixed(i) .or. fixed(a%col(k))) a%val(k) = merge(1.0_dp, 0.0_dp, fixed(i) .and. a%col(k) == i)
         end do
      end do
   end subroutine dirichlet_rows

   subroutine test_galerkin_dense(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t) :: p
      type(csr_t) :: pr, r, a, c
      real(dp), allocatable :: pd(:, :), ad(:, :), cd(:, :), pt(:), rt(:)
      logical, allocatable :: fine_fixed(:), coarse_fixed(:)
      integer(ip), allocatable :: injection(:)
      integer(ip) :: i, j
      type(halo_t) :: coarse_halo
      type(comm_t) :: one_rank

      call square_with_prolongation(3, h, p, pr, err)
      if (allocated(err)) return
      r = pr%transposed()
      a = p%stiffness
      do i = 1, a%n
         a%val(a%find(i, i)) = a%val(a%find(i, i)) + 0.1_dp*mod(i, 5)
      end do
      ! fixed: the left half of the square and every seventh unknown
      allocate (fine_fixed(a%n), coarse_fixed(pr%ncol), injection(pr%ncol))
      do i = 1, a%n
         fine_fixed(i) = h%meshes(3)%vertices(1, p%interior(i)) < -0.3_dp .or. mod(i, 7) == 0
      end do
      do i = 1, pr%n
         if (pr%row_ptr(i + 1) - pr%row_ptr(i) == 1 .and. pr%val(pr%row_ptr(i)) == 1.0_dp) &
            injection(pr%col(pr%row_ptr(i))) = i
      end do
      coarse_fixed = fine_fixed(injection)
      call dirichlet_rows(a, fine_fixed)
      call galerkin_pattern(r, a, pr, c)
      allocate (pt(pr%nnz()), rt(r%nnz()))
      call truncate_transfer(pr, r, fine_fixed, coarse_fixed, pt, rt)
      call coarse_halo%init_whole(one_rank, pr%ncol)
      call galerkin_values(r, rt, a, pr, pt, coarse_fixed, coarse_halo, c)

      ! the same product with dense matrices
      pd = dense(pr)
      do i = 1, pr%n
         do j = 1, pr%ncol
            if (fine_fixed(i) .or. coarse_fixed(j)) pd(i, j) = 0.0_dp
         end do
      end do
      ad = dense(a)
      cd = matmul(transpose(pd), matmul(ad, pd))
      do i = 1, pr%ncol
         if (coarse_fixed(i) .or. .not. cd(i, i) > 0.0_dp) then
            cd(i, :) = 0.0_dp
            cd(i, i) = 1.0_dp
         end if
      end do
      call check(err, count(coarse_fixed) > 0 .and. count(.not. coarse_fixed) > 0, 'both kinds of coarse unknown')
      call check(err, maxval(abs(dense(c) - cd)) <= 1.0e-14_dp*maxval(abs(cd)), 'sparse and dense products agree')
      call check(err, maxval(abs(dense(c) - transpose(dense(c)))) <= 1.0e-14_dp*maxval(abs(cd)), 'symmetric')
   end subroutine test_galerkin_dense

   !> Nested P1 spaces: the coarse stiffness is the fine one restricted to coarse functions.
   subroutine test_galerkin_rediscretizes(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t) :: p, pc
      type(constant_data_t) :: data
      type(csr_t) :: pr, r, c
      logical, allocatable :: none(:)
      type(halo_t) :: coarse_halo
      type(comm_t) :: one_rank

      call square_with_prolongation(4, h, p, pr, err)
      if (allocated(err)) return
      call pc%init(h%meshes(3), data, err)
      if (allocated(err)) return
      r = pr%transposed()
      call galerkin_pattern(r, p%stiffness, pr, c)
      allocate (none(pr%ncol))
      none = .false.
      call coarse_halo%init_whole(one_rank, pr%ncol)
      call galerkin_values(r, r%val, p%stiffness, pr, pr%val, none, coarse_halo, c)
      call check(err, maxval(abs(dense(c) - dense(pc%stiffness))) <= 1.0e-13_dp, &
                 'Pᵀ K_fine P equals K assembled on the coarse mesh')
   end subroutine test_galerkin_rediscretizes

   !> Richardson with one V-cycle per step on K u = b: the mean contraction over 8 steps.
   real(dp) function contraction(mg, a) result(rate)
      type(multigrid_t), intent(inout) :: mg
      type(csr_t), intent(in) :: a

      real(dp), allocatable :: x_true(:), b(:), x(:), r(:), z(:)
      real(dp) :: e0
      integer(i8) :: state
      integer :: it

      allocate (x_true(a%n), b(a%n), x(a%n), r(a%n), z(a%n))
      state = 42_i8
      call fill_random(state, x_true)
      call a%matvec(x_true, b)
      x = 0.0_dp
      e0 = norm2(x_true)
      do it = 1, 8
         call a%residual(b, x, r)
         call mg%vcycle(r, z)
         x = x + z
      end do
      rate = (norm2(x - x_true)/e0)**(1.0_dp/8)
   end function contraction

   subroutine test_vcycle_contraction(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: mg
      type(multigrid_options_t) :: options
      real(dp) :: rates(3)
      integer :: k, levels
      character(len=64) :: msg

      do k = 1, 3
         levels = 2*k + 1
         call square_with_transfers(levels, h, p, transfer, err)
         if (allocated(err)) return
         call mg%init(p%stiffness, transfer, levels, options, .true., err)
         if (allocated(err)) return
         rates(k) = contraction(mg, p%stiffness)
      end do
      write (msg, '("rates ",3f7.4)') rates
      call check(err, all(rates < 0.2_dp), 'a V-cycle reduces the error at least fivefold: '//trim(msg))
      ! coarse meshes lack the smoothest modes; from level 5 on the rate has settled
      call check(err, rates(3) < 1.15_dp*rates(2), 'the rate does not grow with the mesh: '//trim(msg))
   end subroutine test_vcycle_contraction

   subroutine test_vcycle_fixed(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: mg
      type(multigrid_options_t) :: options
      type(csr_t), target :: a
      logical, allocatable :: fixed(:)
      real(dp), allocatable :: b(:), z(:)
      integer(i8) :: state
      integer(ip) :: i
      real(dp) :: rate
      character(len=32) :: msg

      call square_with_transfers(5, h, p, transfer, err)
      if (allocated(err)) return
      a = p%stiffness
      allocate (fixed(a%n))
      do i = 1, a%n
         fixed(i) = h%meshes(5)%vertices(1, p%interior(i)) < -0.2_dp .or. mod(i, 11) == 0
         a%val(a%find(i, i)) = a%val(a%find(i, i)) + 0.5_dp*mod(i, 3)
      end do
      call dirichlet_rows(a, fixed)
      call mg%init(a, transfer, 5, options, .false., err)
      if (allocated(err)) return
      call mg%refresh(fixed, err)
      if (allocated(err)) return
      allocate (b(a%n), z(a%n))
      state = 7_i8
      call fill_random(state, b)
      b = merge(0.0_dp, b, fixed)
      call mg%vcycle(b, z)
      call check(err, all(merge(z, 0.0_dp, fixed) == 0.0_dp), 'fixed unknowns stay exactly zero')
      rate = contraction(mg, a)
      write (msg, '("rate ",f7.4)') rate
      call check(err, rate < 0.3_dp, 'the truncated hierarchy still converges fast: '//trim(msg))
   end subroutine test_vcycle_fixed

   !> Newton matrix of the square problem for a Newton-min (fb = .false.) or Fischer–Burmeister
   !> linearization with a contact region in the left half.
   subroutine newton_matrix(levels, fb, h, p, sys, err)
      integer, intent(in) :: levels
      logical, intent(in) :: fb
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), target, intent(out) :: p
      type(newton_system_t), intent(inout) :: sys
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: da(:), db(:)
      logical, allocatable :: active(:)
      integer(ip) :: i

      call square_problem(levels, h, p, err, mu2=4.0_dp)
      if (allocated(err)) return
      call sys%init(p, .true.)
      allocate (active(p%n), da(p%n), db(p%n))
      do i = 1, p%n
         active(i) = h%meshes(levels)%vertices(1, p%interior(i)) < 0.0_dp .or. mod(i, 13) == 0
      end do
      if (fb) then
         ! a spread of Fischer–Burmeister rows, from nearly active to nearly inactive
         do i = 1, p%n
            da(i) = merge(-0.9_dp, -0.05_dp, active(i)) - 0.01_dp*mod(i, 3)
            db(i) = merge(-0.02_dp, -0.8_dp, active(i))
         end do
         da(1) = -1.0_dp
         db(1) = 0.0_dp
      else
         da = merge(1.0_dp, 0.0_dp, active)
         db = merge(0.0_dp, 1.0_dp, active)
      end if
      call sys%set_jacobian(da, db)
   end subroutine newton_matrix

   subroutine test_elimination_exact(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(newton_system_t) :: sys
      type(multigrid_transfer_t), target :: none
      type(elimination_preconditioner_t) :: prec
      type(multigrid_options_t) :: options
      real(dp), allocatable :: r(:), z(:), az(:)
      integer(i8) :: state
      integer :: k
      character(len=48) :: msg

      do k = 1, 2
         call newton_matrix(3, k == 2, h, p, sys, err)
         if (allocated(err)) return
         call none%init([csr_t ::], err, halos=[p%halo], coarse_keys=p%global)
         if (allocated(err)) return
         call prec%init(p, none, 0, options, err)
         if (allocated(err)) return
         ! through the assembled matrix's C-rows, the path of setup(a)
         call prec%setup(sys%a, err)
         if (allocated(err)) return
         allocate (r(3*p%n), z(3*p%n), az(3*p%n))
         state = 99_i8
         call fill_random(state, r)
         call prec%apply(r, z)
         call sys%a%matvec(z, az)
         write (msg, '("relative residual ",es9.2)') norm2(az - r)/norm2(r)
         call check(err, norm2(az - r) <= 1.0e-11_dp*norm2(r), &
                    trim(merge('Fischer-Burmeister', 'Newton-min        ', k == 2))//': exact inverse, '//trim(msg))
         deallocate (r, z, az)
      end do
   end subroutine test_elimination_exact

   !> The membranes μ1 = 1, μ2 = 4 on the square refined `levels` times, with the transfers of
   !> its hierarchy.
   subroutine membranes_on_square(levels, h, p, transfer, err)
      integer, intent(in) :: levels
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), intent(out) :: p
      type(multigrid_transfer_t), intent(out) :: transfer
      type(error_t), allocatable, intent(out) :: err

      call square_with_transfers(levels, h, p, transfer, err, mu2=4.0_dp)
   end subroutine membranes_on_square

   !> The square refined `levels` times, its problem (square_problem: the stiffness K is that of
   !> any data) and the interior prolongations of every level.
   subroutine square_with_transfers(levels, h, p, transfer, err, mu2)
      integer, intent(in) :: levels
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), intent(out) :: p
      type(multigrid_transfer_t), intent(out) :: transfer
      type(error_t), allocatable, intent(out) :: err
      real(dp), intent(in), optional :: mu2

      call square_problem(levels, h, p, err, mu2)
      if (allocated(err)) return
      call transfer%init(interior_prolongations(h, levels), err)
   end subroutine square_with_transfers

   !> C-function rows for step `step` of a made-up Newton iteration on the square: Fischer–
   !> Burmeister rows whose contact region (x < x_contact) grows from step to step, shifts that
   !> change only in the upper part (y > 0.3), and exactly fixed rows (b = 0) at every 13th (step
   !> 1) or 17th (later) unknown of the contact region.
   subroutine made_up_step(h, p, levels, step, da, db)
      type(mesh_hierarchy_t), intent(in) :: h
      type(discrete_problem_t), intent(in) :: p
      integer, intent(in) :: levels, step
      real(dp), intent(out) :: da(:), db(:)

      real(dp) :: x, y, x_contact
      integer(ip) :: i

      x_contact = -0.3_dp + 0.2_dp*step
      do i = 1, p%n
         x = h%meshes(levels)%vertices(1, p%interior(i))
         y = h%meshes(levels)%vertices(2, p%interior(i))
         da(i) = merge(-0.9_dp, -0.05_dp, x < x_contact) - 0.01_dp*mod(i, 3)
         db(i) = merge(-0.02_dp, -0.8_dp, x < x_contact)
         if (y > 0.3_dp) db(i) = db(i)*(1 + 0.1_dp*step)
         if (x < x_contact .and. mod(i, merge(13, 17, step == 1)) == 0) db(i) = 0.0_dp
      end do
   end subroutine made_up_step

   !> A Newton step changes the fixed rows and part of the shift: the w-block hierarchy updated
   !> on the rows the change reaches (it starts as the S-block's) must hold the bits of one
   !> rebuilt whole for that step, and agree to round-off with the plain product P_tᵀ A P_t of
   !> the finest operator stored as a matrix, K + diag(shift) cut at the fixed rows made afresh
   !> here (no split of K and shift). The hierarchy never stores that operator: applied from K,
   !> its diagonal, its products and its smoother have the stored matrix's bits. Five steps: from the start to a
   !> Fischer–Burmeister step, to another, then to a Newton-min step (no shift, rows come free),
   !> another, and one that flips two rows.
   subroutine test_partial_rebuild(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: levels = 4
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(elimination_preconditioner_t) :: updated
      type(multigrid_t) :: whole, plain
      type(multigrid_options_t) :: options
      real(dp), allocatable :: da(:, :), db(:, :)
      logical, allocatable :: fixed_before(:)
      real(dp) :: scale, deviation
      integer :: l, step
      logical :: identical, both_ways, partial, refilled
      character(len=80) :: msg
      type(csr_t), target :: expected
      real(dp), allocatable :: x(:), y_cut(:), y_stored(:)
      integer(ip) :: i

      call membranes_on_square(levels, h, p, transfer, err)
      if (allocated(err)) return
      allocate (da(p%n, 5), db(p%n, 5))
      call made_up_step(h, p, levels, 1, da(:, 1), db(:, 1))
      call made_up_step(h, p, levels, 2, da(:, 2), db(:, 2))
      ! Newton-min: contact in the second step's contact region except at its fixed rows, which
      ! come free
      da(:, 3) = merge(1.0_dp, 0.0_dp, db(:, 2) /= 0.0_dp .and. da(:, 2) < -0.5_dp)
      db(:, 3) = 1.0_dp - da(:, 3)
      ! and another, which fixes those rows again and frees every fifth of the region
      da(:, 4) = merge(1.0_dp, 0.0_dp, da(:, 2) < -0.5_dp .and. mod([(l, l=1, p%n)], 5) /= 0)
      db(:, 4) = 1.0_dp - da(:, 4)
      ! and a last one that frees one row and fixes another (few marks: they are spread, not
      ! gathered)
      da(:, 5) = da(:, 4)
      da(findloc(da(:, 4), 1.0_dp, dim=1), 5) = 0.0_dp
      da(findloc(da(:, 4), 0.0_dp, dim=1), 5) = 1.0_dp
      db(:, 5) = 1.0_dp - da(:, 5)
      call updated%init(p, transfer, levels, options, err)
      if (allocated(err)) return
      do step = 1, 5
         fixed_before = updated%fixed
         call updated%set_linearization(da(:, step), db(:, step), err)
         if (allocated(err)) return
         both_ways = any(updated%fixed .and. .not. fixed_before) .and. any(fixed_before .and. .not. updated%fixed)
         ! the finest operator, refilled on the changed rows, against K + diag(shift) made afresh
         expected = p%stiffness
         call dirichlet_rows(expected, updated%fixed)
         do i = 1, p%n
            if (.not. updated%fixed(i)) expected%val(expected%find(i, i)) = expected%val(expected%find(i, i)) + &
                                                                          updated%shift(i)
         end do
         ! the hierarchy applies it from K, cut: its diagonal and its product (of a vector that
         ! vanishes at the fixed unknowns, as the V-cycle's do) are those of the stored matrix
         refilled = all(updated%w_mg%cut_diagonal == [(expected%val(expected%find(i, i)), i=1, p%n)])
         x = merge(0.0_dp, [(sin(0.7_dp*i), i=1, p%n)], updated%fixed)
         allocate (y_cut(p%n), y_stored(p%n))
         call p%stiffness%cut_matvec(updated%w_mg%cut_diagonal, updated%fixed, x, y_cut)
         call expected%matvec(x, y_stored)
         refilled = refilled .and. all(y_cut == y_stored)
         deallocate (y_cut, y_stored)
         partial = .not. all(updated%w_mg%levels(levels - 1)%updated)
         call whole%init(p%stiffness, transfer, levels, options, .false., err, base=p%stiffness)
         if (allocated(err)) return
         call whole%refresh(updated%fixed, err, shift=updated%shift)
         if (allocated(err)) return
         call plain%init(expected, transfer, levels, options, .false., err)
         if (allocated(err)) return
         call plain%refresh(updated%fixed, err)
         if (allocated(err)) return
         identical = .true.
         deviation = 0.0_dp
         do l = 0, levels - 1
            associate (a => updated%w_mg%levels(l)%a)
               identical = identical .and. all(a%val == whole%levels(l)%a%val)
               scale = maxval(abs(plain%levels(l)%a%val))
               deviation = max(deviation, maxval(abs(a%val - plain%levels(l)%a%val))/scale)
            end associate
         end do
         ! and the smoothers, set up on the updated rows
         do l = 1, levels
            associate (smoother => updated%w_mg%levels(l)%smoother)
               identical = identical .and. all(smoother%inv_diag == whole%levels(l)%smoother%inv_diag) .and. &
                           all(smoother%part_sum == whole%levels(l)%smoother%part_sum) .and. &
                           smoother%upper == whole%levels(l)%smoother%upper
            end associate
         end do
         ! the finest smoother, set up from the cut operator, and the stored matrix's
         associate (smoother => updated%w_mg%levels(levels)%smoother)
            identical = identical .and. all(smoother%inv_diag == plain%levels(levels)%smoother%inv_diag) .and. &
                        all(smoother%part_sum == plain%levels(levels)%smoother%part_sum)
         end associate
         write (msg, '("step ",i0,": largest relative deviation ",es9.2)') step, deviation
         call check(err, both_ways .or. step == 1, trim(msg)//': rows became fixed and free')
         call check(err, refilled, trim(msg)//': the w-block operator is K + diag(shift), truncated')
         ! from the start and from Fischer–Burmeister to Newton-min every shift changes
         call check(err, partial .or. step == 1 .or. step == 3, trim(msg)//': the update is partial')
         call check(err, identical, trim(msg)//': the partial update has the bits of a whole rebuild')
         call check(err, deviation <= 1.0e-14_dp, trim(msg)//': split product and plain product agree')
         if (allocated(err)) return
      end do
   end subroutine test_partial_rebuild

   !> A hierarchy assembled by init (patterns and values in one pass per level) holds the bits of
   !> one whose patterns init analysed and whose values refresh computed.
   subroutine test_assembled_hierarchy(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: levels = 4
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: assembled, refreshed
      type(multigrid_options_t) :: options
      logical :: identical
      integer :: l

      call square_with_transfers(levels, h, p, transfer, err)
      if (allocated(err)) return
      call assembled%init(p%stiffness, transfer, levels, options, .true., err)
      if (allocated(err)) return
      call refreshed%init(p%stiffness, transfer, levels, options, .false., err)
      if (allocated(err)) return
      call refreshed%refresh(refreshed%levels(levels)%fixed, err)
      if (allocated(err)) return
      identical = .true.
      do l = 0, levels - 1
         associate (a => assembled%levels(l)%a, b => refreshed%levels(l)%a)
            identical = identical .and. all(a%row_ptr == b%row_ptr) .and. all(a%col == b%col) .and. all(a%val == b%val)
         end associate
      end do
      do l = 1, levels
         identical = identical .and. all(assembled%levels(l)%smoother%inv_diag == refreshed%levels(l)%smoother%inv_diag) &
                     .and. assembled%levels(l)%smoother%upper == refreshed%levels(l)%smoother%upper
      end do
      call check(err, identical, 'patterns, values and smoothers agree bit for bit')
   end subroutine test_assembled_hierarchy

   !> A frozen hierarchy (the S-block's, once the w-block has started from it) has dropped what
   !> only a refresh reads: its V-cycle gives the bits of before, and a refresh is refused.
   subroutine test_frozen_hierarchy(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: levels = 4
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(multigrid_t) :: mg
      type(multigrid_options_t) :: options
      real(dp), allocatable :: b(:), before(:), after(:)
      type(error_t), allocatable :: refused
      integer(ip) :: i

      call square_with_transfers(levels, h, p, transfer, err)
      if (allocated(err)) return
      call mg%init(p%stiffness, transfer, levels, options, .true., err)
      if (allocated(err)) return
      b = [(sin(0.3_dp*i), i=1, p%n)]
      allocate (before(p%n), after(p%n))
      call mg%vcycle(b, before)
      call mg%freeze()
      call mg%vcycle(b, after)
      call check(err, all(after == before), 'the frozen V-cycle gives the bits of before')
      call check(err, .not. allocated(mg%levels(levels)%smoother%part_diag) .and. &
                 .not. allocated(mg%levels(levels - 1)%part_diag), 'the refresh data are gone')
      call mg%refresh([(.false., i=1, p%n)], refused)
      call check(err, allocated(refused), 'a refresh of a frozen hierarchy is refused')
   end subroutine test_frozen_hierarchy

   !> A release frees the hierarchies, the w-block operator and the transfers' restrictions; the
   !> preconditioner applied afterwards (GMRES going on) rebuilds them for the same Newton step
   !> and gives the bits of before, and one released and then given the next step's rows gives
   !> the bits of one built for that step from scratch (no trace of the steps before the release).
   subroutine test_release(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: levels = 3
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(multigrid_transfer_t), target :: transfer
      type(elimination_preconditioner_t) :: prec, fresh
      type(multigrid_options_t) :: options
      real(dp), allocatable :: da(:, :), db(:, :), r(:), z_before(:), z_after(:), z_fresh(:)
      integer(i8) :: state
      integer :: step

      call membranes_on_square(levels, h, p, transfer, err)
      if (allocated(err)) return
      allocate (da(p%n, 3), db(p%n, 3), r(3*p%n), z_before(3*p%n), z_after(3*p%n), z_fresh(3*p%n))
      do step = 1, 3
         call made_up_step(h, p, levels, step, da(:, step), db(:, step))
      end do
      state = 17_i8
      call fill_random(state, r)
      call prec%init(p, transfer, levels, options, err)
      if (allocated(err)) return
      do step = 1, 2
         call prec%set_linearization(da(:, step), db(:, step), err)
         if (allocated(err)) return
      end do
      call prec%apply(r, z_before)
      call prec%release()
      call check(err, .not. allocated(prec%w_mg%levels) .and. .not. allocated(prec%s_mg%levels) .and. &
                 .not. allocated(prec%w_matrix%val) .and. .not. allocated(prec%shift) .and. &
                 .not. allocated(transfer%r), &
                 'the release frees the hierarchies, the w-block operator, the row data and the restrictions')
      call prec%apply(r, z_after)
      call check(err, all(z_after == z_before), 'applied after a release: the bits of before')
      call check(err, allocated(transfer%r), 'the rebuild transposed the prolongations again')
      ! (err is intent(out) in what follows: a failed check ends the test here)
      if (allocated(err)) return
      call prec%release()
      call prec%set_linearization(da(:, 3), db(:, 3), err)
      if (allocated(err)) return
      call prec%apply(r, z_after)
      call fresh%init(p, transfer, levels, options, err)
      if (allocated(err)) return
      call fresh%set_linearization(da(:, 3), db(:, 3), err)
      if (allocated(err)) return
      call fresh%apply(r, z_fresh)
      call check(err, all(z_after == z_fresh), 'the next step after a release: the bits of a preconditioner built for it')
      call check(err, any(z_fresh /= z_before), 'the two steps differ (the comparison can fail)')
   end subroutine test_release

   subroutine test_gmres_iterations(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(newton_system_t), target :: sys
      type(newton_operator_t) :: op
      type(multigrid_transfer_t), target :: transfer
      type(elimination_preconditioner_t) :: prec
      type(multigrid_options_t) :: mg_options
      type(gmres_options_t) :: options
      type(gmres_monitor_t) :: monitor
      type(euclidean_product_t) :: dot
      real(dp), allocatable :: b(:), x(:), ax(:)
      integer(i8) :: state
      integer :: k, levels, its(2, 2)
      character(len=64) :: msg

      options%rtol = 1.0e-10_dp
      do k = 1, 2
         do levels = 3, 5, 2
            call newton_matrix(levels, k == 2, h, p, sys, err)
            if (allocated(err)) return
            call transfer%init(interior_prolongations(h, levels), err)
            if (allocated(err)) return
            call prec%init(p, transfer, levels, mg_options, err)
            if (allocated(err)) return
            call prec%set_linearization(sys%da, sys%db, err)
            if (allocated(err)) return
            op%sys => sys
            allocate (b(3*p%n), x(3*p%n), ax(3*p%n))
            state = 5_i8
            call fill_random(state, b)
            x = 0.0_dp
            call gmres_solve(op, prec, dot, b, x, options, monitor, err)
            if (allocated(err)) return
            call sys%a%matvec(x, ax)
            call check(err, norm2(ax - b) <= 1.0e-9_dp*norm2(b), 'GMRES reaches the tolerance (true residual)')
            its(k, (levels - 1)/2) = monitor%iterations
            deallocate (b, x, ax)
         end do
      end do
      write (msg, '("iterations (min: ",i0,", ",i0,"; fb: ",i0,", ",i0,")")') its(1, :), its(2, :)
      call check(err, all(its <= 12), 'at most 12 iterations to 1e-10: '//trim(msg))
      call check(err, its(1, 2) <= its(1, 1) + 2 .and. its(2, 2) <= its(2, 1) + 2, &
                 'the count does not grow with the mesh: '//trim(msg))
   end subroutine test_gmres_iterations
end module test_multigrid
