!> Exact Newton-min: the discrete solution satisfies the discrete equations and the
!> complementarity conditions to round-off, the stopping test is the paper's, and failures come
!> back as a status rather than a crash.
module test_newton
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: c_function_min, c_function_fb
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_cfun, only: cfun_min, cfun_fb
   use twomem_newton_solver, only: newton_options_t, newton_result_t, newton_solve
   use twomem_newton_inner, only: check_schedule_t, newton_observer_t
   use twomem_newton_fb_finish, only: fb_finish_t
   use twomem_newton_history, only: history_row_t, not_computed
   use twomem_newton_settle, only: settle_contact
   use twomem_newton_system, only: newton_system_t
   use twomem_newton_residual, only: nonlinear_residual_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_refinement, only: square_problem
   implicit none
   private

   public :: collect_newton

   !> Answers the partial estimates with set values and counts what the schedule asks.
   type, extends(newton_observer_t) :: counting_observer_t
      real(dp) :: eta_lin = 0.0_dp, eta_disc = 0.0_dp
      integer :: lin_calls = 0, disc_calls = 0, drops = 0, observes = 0
      !> the size of the last iterate it was shown
      integer :: n = 0
   contains
      procedure :: observe => observe_counted
      procedure :: linearization_estimate => counted_lin
      procedure :: discretization_estimate => counted_disc
      procedure :: drop_partial => counted_drop
   end type counting_observer_t

contains

   subroutine collect_newton(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('cfun_min_jacobian', test_cfun_min), &
               new_unittest('cfun_jacobians_finite_differences', test_cfun_fd), &
               new_unittest('cfun_fb_values_and_kink', test_cfun_fb), &
               new_unittest('discrete_equations_roundoff', test_discrete_equations), &
               new_unittest('iteration_limit_reported', test_limit), &
               new_unittest('check_schedule_predicts_the_newton_test', test_check_schedule), &
               new_unittest('check_schedule_stages', test_check_stages), &
               new_unittest('fb_finish_schedule', test_fb_finish), &
               new_unittest('settle_restores_the_discrete_solution', test_settle), &
               new_unittest('residual_tracks_the_merit', test_tracked_merit)]
   end subroutine collect_newton

   subroutine test_cfun_min(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp) :: c, da, db

      call cfun_min(0.3_dp, 0.5_dp, c, da, db)
      call check(err, c == 0.3_dp .and. da == 1 .and. db == 0, 'a-row where a < b')
      call cfun_min(0.5_dp, -0.1_dp, c, da, db)
      call check(err, c == -0.1_dp .and. da == 0 .and. db == 1, 'b-row where b < a')
      call cfun_min(0.2_dp, 0.2_dp, c, da, db)
      call check(err, da == 1 .and. db == 0, 'ties take the a-row')
   end subroutine test_cfun_min

   !> Central differences of both C-functions at points away from their kinks (a = b for
   !> min, a = b = 0 for FB) agree with the analytic Jacobian to the differencing error.
   subroutine test_cfun_fd(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp), parameter :: pts(2, 6) = reshape([0.3_dp, 0.5_dp, 0.5_dp, -0.1_dp, -2.0_dp, 1.0_dp, &
                                                  1.0e-3_dp, 2.0e-3_dp, 3.0_dp, 4.0_dp, -1.0_dp, -1.5_dp], [2, 6])
      real(dp) :: c, da, db, cp, cm, dummy1, dummy2, step, fd_a, fd_b
      integer :: k, which

      do which = 1, 2
         do k = 1, size(pts, 2)
            associate (a => pts(1, k), b => pts(2, k))
               step = 1.0e-6_dp*max(1.0_dp, abs(a), abs(b))
               call eval(which, a, b, c, da, db)
               call eval(which, a + step, b, cp, dummy1, dummy2)
               call eval(which, a - step, b, cm, dummy1, dummy2)
               fd_a = (cp - cm)/(2*step)
               call eval(which, a, b + step, cp, dummy1, dummy2)
               call eval(which, a, b - step, cm, dummy1, dummy2)
               fd_b = (cp - cm)/(2*step)
               call check_close(err, da, fd_a, 0.0_dp, 1.0e-6_dp, 'dC/da by finite differences')
               call check_close(err, db, fd_b, 0.0_dp, 1.0e-6_dp, 'dC/db by finite differences')
            end associate
         end do
      end do

   contains

      subroutine eval(which, a, b, c, da, db)
         integer, intent(in) :: which
         real(dp), intent(in) :: a, b
         real(dp), intent(out) :: c, da, db

         if (which == 1) then
            call cfun_min(a, b, c, da, db)
         else
            call cfun_fb(a, b, c, da, db)
         end if
      end subroutine eval
   end subroutine test_cfun_fd

   subroutine test_cfun_fb(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp) :: c, da, db

      call cfun_fb(0.0_dp, 0.7_dp, c, da, db)
      call check_close(err, c, 0.0_dp, 0.0_dp, 1.0e-16_dp, 'C = 0 on the axis b > 0')
      call cfun_fb(0.7_dp, 0.0_dp, c, da, db)
      call check_close(err, c, 0.0_dp, 0.0_dp, 1.0e-16_dp, 'C = 0 on the axis a > 0')
      call cfun_fb(-0.3_dp, 0.0_dp, c, da, db)
      call check_close(err, c, -0.3_dp*(-2), 0.0_dp, 1.0e-15_dp, 'C = 2|a| for a < 0 = b')
      ! cancellation-free where both are positive: C ≈ −b for a ≫ b
      call cfun_fb(1.0e8_dp, 1.0e-8_dp, c, da, db)
      call check_close(err, c, -1.0e-8_dp, 1.0e-12_dp, 0.0_dp, 'no cancellation')
      call cfun_fb(0.0_dp, 0.0_dp, c, da, db)
      call check_close(err, da, 1/sqrt(2.0_dp) - 1, 0.0_dp, 1.0e-15_dp, 'Clarke element at the kink')
      call check_close(err, db, 1/sqrt(2.0_dp) - 1, 0.0_dp, 1.0e-15_dp, 'Clarke element at the kink')
   end subroutine test_cfun_fb

   subroutine solve_square(levels, max_it, p, res, err)
      integer, intent(in) :: levels, max_it
      type(discrete_problem_t), intent(out) :: p
      type(newton_result_t), intent(out) :: res
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t) :: h
      type(newton_options_t) :: opt
      real(dp), allocatable :: x0(:)

      call square_problem(levels, h, p, err)
      if (allocated(err)) return
      opt%verbose = .false.
      opt%max_it = max_it
      x0 = [spread(p%g, 1, p%n), spread(0.0_dp, 1, 2*p%n)]
      call newton_solve(p, opt, x0, res, err)
   end subroutine solve_square

   subroutine test_discrete_equations(err)
      type(error_t), allocatable, intent(out) :: err
      type(discrete_problem_t) :: p
      type(newton_result_t) :: res
      real(dp), allocatable :: s1(:), s2(:), w(:), lam(:)
      integer(ip) :: n

      call solve_square(4, 100, p, res, err)
      if (allocated(err)) return
      call check(err, res%converged, 'converged: '//res%status)
      n = p%n
      allocate (s1(n), s2(n))
      call p%stiffness%matvec(res%x(1:n), s1)
      call p%stiffness%matvec(res%x(n + 1:2*n), s2)
      lam = res%x(2*n + 1:)
      w = res%x(1:n) - res%x(n + 1:2*n)
      call check(err, maxval(abs(p%mu1*s1 - p%mass*lam - p%f(1:p%n))) < 1.0e-13_dp*maxval(abs(p%f(1:p%n))) + 1e-15_dp, &
                 'first membrane equation')
      call check(err, maxval(abs(p%mu2*s2 + p%mass*lam - p%f(p%n + 1:))) < 1.0e-13_dp*maxval(abs(p%f(p%n + 1:))) + 1e-15_dp, &
                 'second membrane equation')
      call check(err, minval(w) > -1.0e-14_dp, 'u1 - u2 >= 0')
      call check(err, minval(lam) > -1.0e-14_dp, 'lambda >= 0')
      call check(err, maxval(abs(min(w, lam))) < 1.0e-14_dp, 'complementarity')
      call check(err, count(lam > 0) > 0 .and. count(w > 0) > 0, 'both contact and no contact')
      call check(err, res%history%rows(res%history%n)%lin_residual <= 1.0e-10_dp, 'paper stopping test')
   end subroutine test_discrete_equations

   !> The discrete solution (UMFPACK, checked against its equations above) is a fixed point of
   !> the settling, and a vertex whose multiplier alone breaks complementarity (its neighbours'
   !> rows do not read it) gets its solution values back from its own local problem.
   subroutine test_settle(err)
      type(error_t), allocatable, intent(out) :: err
      type(discrete_problem_t) :: p
      type(newton_result_t) :: res
      real(dp), allocatable :: x(:)
      integer(ip) :: n, free, contact, settled
      real(dp) :: scale

      call solve_square(4, 100, p, res, err)
      if (allocated(err)) return
      call check(err, res%converged, 'converged: '//res%status)
      if (allocated(err)) return
      n = p%n
      scale = maxval(abs(res%x))
      x = res%x
      call settle_contact(p, x, settled)
      call check(err, maxval(abs(x - res%x)) <= 1.0e-12_dp*scale, 'the solution is a fixed point')
      ! a free vertex with a multiplier, a contact vertex with a negative one
      free = findloc(res%x(1:n) - res%x(n + 1:2*n) > 0.1_dp*scale, .true., dim=1, kind=ip)
      contact = findloc(res%x(2*n + 1:) > 0.0_dp, .true., dim=1, kind=ip)
      call check(err, free > 0 .and. contact > 0, 'the case has free and contact vertices')
      if (allocated(err)) return
      x = res%x
      x(2*n + free) = 1.0_dp
      x(2*n + contact) = -1.0_dp
      call settle_contact(p, x, settled)
      call check(err, settled >= 2, 'the broken vertices were relaxed')
      call check(err, maxval(abs(x - res%x)) <= 1.0e-12_dp*scale, 'both vertices restored')
   end subroutine test_settle

   !> The merit that `relative` leaves when tracking (the Newton driver's line search takes it
   !> instead of calling `merit`) is `merit`'s value to the last bit, tracking leaves the
   !> relative residual as it was, and both are the norms their formulas give when computed
   !> here from the matrices (both C-functions, an iterate off the solution).
   subroutine test_tracked_merit(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(discrete_problem_t), target :: p
      type(newton_system_t), target :: sys
      type(nonlinear_residual_t) :: plain, tracking
      real(dp), allocatable :: x(:), c(:), da(:), db(:), s1(:), s2(:), r1(:), r2(:), cc(:)
      real(dp) :: rel_plain, rel_tracking, merit, expected_merit, expected_rel
      integer(ip) :: n, i
      integer :: which

      call square_problem(3, h, p, err)
      if (allocated(err)) return
      n = p%n
      ! (g, 0, 0) moved by a smooth non-trivial perturbation: contact and free vertices, λ of both signs
      allocate (x(3*n), c(n), da(n), db(n), s1(n), s2(n), cc(n))
      do i = 1, n
         x(i) = p%g + 0.01_dp*sin(0.7_dp*i)
         x(n + i) = 0.02_dp*cos(1.3_dp*i)
         x(2*n + i) = 0.5_dp*sin(0.37_dp*i)
      end do
      call sys%init(p, .false.)
      call p%stiffness%matvec(x(1:n), s1)
      call p%stiffness%matvec(x(n + 1:2*n), s2)
      r1 = p%f(1:n) - (p%mu1*s1 - p%mass*x(2*n + 1:))
      r2 = p%f(n + 1:) - (p%mu2*s2 + p%mass*x(2*n + 1:))
      do which = c_function_min, c_function_fb
         call plain%init(sys, which, track_merit=.false.)
         call tracking%init(sys, which, track_merit=.true.)
         call plain%relative(x, rel_plain, c, da, db)
         call tracking%relative(x, rel_tracking, c, da, db)
         merit = tracking%merit(x)
         call check(err, rel_tracking == rel_plain, 'tracking leaves the relative residual as it was')
         call check(err, tracking%last_merit == merit, 'the tracked merit is merit''s to the last bit')
         if (which == c_function_min) then
            cc = min(x(1:n) - x(n + 1:2*n), x(2*n + 1:))
         else
            cc = sqrt((x(1:n) - x(n + 1:2*n))**2 + x(2*n + 1:)**2) - (x(1:n) - x(n + 1:2*n)) - x(2*n + 1:)
         end if
         expected_merit = sqrt(sum((r1/p%mass)**2) + sum((r2/p%mass)**2) + sum(cc**2))
         expected_rel = sqrt(sum(r1**2) + sum(r2**2) + sum(cc**2))/sqrt(sum(p%f**2))
         call check_close(err, merit, expected_merit, 1.0e-12_dp, 0.0_dp, 'the merit is the formula''s')
         call check_close(err, rel_plain, expected_rel, 1.0e-12_dp, 0.0_dp, 'the relative residual is the formula''s')
         if (allocated(err)) return
      end do
   end subroutine test_tracked_merit

   subroutine test_limit(err)
      type(error_t), allocatable, intent(out) :: err
      type(discrete_problem_t) :: p
      type(newton_result_t) :: res

      call solve_square(4, 1, p, res, err)
      if (allocated(err)) return
      call check(err, .not. res%converged, 'one step is not enough')
      call check(err, index(res%status, 'iteration limit') > 0, 'status names the limit: '//res%status)
   end subroutine test_limit

   !> Fischer–Burmeister's step kinds: FB until a step moves at most 1% of the contact set, then
   !> active-set steps while they move it, at most three in a row, then FB again; never when
   !> disabled (newton.fb_finish = 'none').
   subroutine test_fb_finish(err)
      type(error_t), allocatable, intent(out) :: err
      type(fb_finish_t) :: fb
      logical :: kinds(8)
      integer :: k
      !> vertices moved by steps 1..8 of a contact set of 10 000
      integer, parameter :: moved(8) = [500, 100, 40, 7, 3, 2, 0, 0]

      fb%enabled = .true.
      do k = 1, size(moved)
         call fb%next_step()
         kinds(k) = fb%active_set_step
         call fb%step_moved(moved(k), 10000)
      end do
      ! 500 > 1%: FB; 100 = 1%: active-set from step 3 on, while the set moves (40, 7, 3), at
      ! most three in a row; step 6 is FB, and its 2 vertices start another streak of active-set
      ! steps, which ends once a step moves none
      call check(err, all(kinds .eqv. [.false., .false., .true., .true., .true., .false., .true., .false.]), &
                 'FB, FB, three active-set steps, FB, one active-set step until the set settles, FB')
      fb = fb_finish_t()
      do k = 1, 3
         call fb%next_step()
         call check(err, .not. fb%active_set_step, 'disabled: FB at every step')
         call fb%step_moved(0, 10000)
      end do
   end subroutine test_fb_finish

   !> The adaptive method's checks: the first evaluates; a later one only where its η_lin passes
   !> γ_lin times the last η_disc; an evaluation that failed (NaN) or a NaN η_lin makes the check
   !> evaluate; 'all' evaluates every check.
   subroutine test_check_schedule(err)
      type(error_t), allocatable, intent(out) :: err
      type(check_schedule_t) :: schedule
      type(history_row_t) :: row

      schedule%predict = .true.
      schedule%gamma_lin = 0.3_dp
      call check(err, schedule%wanted(1.0_dp), 'the first check evaluates')
      row = not_computed()
      row%eta_lin = 1.0e-2_dp
      row%eta_disc = 1.0e-3_dp
      call schedule%remember(row)
      call check(err, .not. schedule%wanted(1.0e-2_dp), 'eta_lin 33 times gamma_lin eta_disc is skipped')
      call check(err, .not. schedule%wanted(3.01e-4_dp), 'just above gamma_lin eta_disc')
      call check(err, schedule%wanted(2.99e-4_dp), 'just below gamma_lin eta_disc')
      call check(err, schedule%wanted(0.0_dp), 'a zero eta_lin evaluates')
      call check(err, schedule%wanted(ieee_nan()), 'an unknown eta_lin evaluates')
      row%eta_disc = ieee_nan()
      call schedule%remember(row)
      call check(err, schedule%wanted(1.0_dp), 'after a failed evaluation the next check evaluates')
      row%eta_disc = 1.0e-3_dp
      call schedule%remember(row)
      schedule%predict = .false.
      call check(err, schedule%wanted(1.0_dp), "estimate.checks = 'all' evaluates every check")
   contains
      real(dp) function ieee_nan()
         use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
         ieee_nan = ieee_value(1.0_dp, ieee_quiet_nan)
      end function ieee_nan
   end subroutine test_check_schedule

   !> The stages of a check (check_schedule_t%screen, %decide): η_lin alone screens a check out
   !> and stays in its row; a screened check goes on to η_disc without asking for η_lin again;
   !> when the Newton test then fails the partial evaluation is dropped (the next check sees
   !> another iterate), and when it holds the evaluation is whole and expected to be the last;
   !> with 'all' nothing partial is asked.
   subroutine test_check_stages(err)
      type(error_t), allocatable, intent(out) :: err
      type(check_schedule_t) :: schedule
      type(counting_observer_t) :: obs
      type(history_row_t) :: row
      real(dp) :: x(3), eta_lin
      logical :: go_on, evaluates, last

      x = 0.0_dp
      schedule%predict = .true.
      schedule%gamma_lin = 0.3_dp
      obs%eta_lin = 1.0e-2_dp
      obs%eta_disc = 1.0e-3_dp
      row = not_computed()
      go_on = schedule%screen(obs, x, row, eta_lin)
      call check(err, go_on .and. eta_lin == 1.0e-2_dp .and. obs%lin_calls == 1, 'the first check goes on past eta_lin')
      if (allocated(err)) return
      evaluates = schedule%decide(obs, x, row, last, screened=eta_lin)
      call check(err, .not. evaluates .and. .not. last, 'eta_lin above gamma_lin eta_disc: no whole evaluation')
      call check(err, obs%lin_calls == 1 .and. obs%disc_calls == 1, 'eta_lin not asked again, eta_disc once')
      call check(err, obs%drops == 1, 'the partial evaluation is dropped')
      call check(err, row%eta_lin == 1.0e-2_dp .and. row%eta_disc == 1.0e-3_dp, 'the row keeps eta_lin and eta_disc')
      if (allocated(err)) return

      row = not_computed()
      go_on = schedule%screen(obs, x, row, eta_lin)
      call check(err, .not. go_on .and. row%eta_lin == 1.0e-2_dp .and. obs%disc_calls == 1, &
                 'the next check is screened out by eta_lin alone, which its row keeps')
      if (allocated(err)) return

      obs%eta_lin = 1.0e-4_dp
      row = not_computed()
      evaluates = schedule%decide(obs, x, row, last)
      call check(err, evaluates .and. last, 'the Newton test holds: a whole evaluation, expected to be the last')
      call check(err, obs%lin_calls == 3 .and. obs%disc_calls == 2 .and. obs%drops == 1, &
                 'decide screens by itself, and keeps the evaluation it will complete')
      if (allocated(err)) return

      schedule%predict = .false.
      go_on = schedule%screen(obs, x, row, eta_lin)
      evaluates = schedule%decide(obs, x, row, last)
      call check(err, go_on .and. evaluates .and. .not. last .and. obs%lin_calls == 3 .and. obs%disc_calls == 2, &
                 "'all': every check evaluates, nothing partial asked")
   end subroutine test_check_stages

   subroutine observe_counted(self, x, row, estimates)
      class(counting_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      type(history_row_t), intent(inout) :: row
      logical, intent(in) :: estimates

      self%observes = self%observes + 1
      self%n = size(x)
      if (estimates) row%eta_disc = self%eta_disc
   end subroutine observe_counted

   function counted_lin(self, x) result(eta)
      class(counting_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp) :: eta

      self%lin_calls = self%lin_calls + 1
      self%n = size(x)
      eta = self%eta_lin
   end function counted_lin

   function counted_disc(self, x) result(eta)
      class(counting_observer_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp) :: eta

      self%disc_calls = self%disc_calls + 1
      self%n = size(x)
      eta = self%eta_disc
   end function counted_disc

   subroutine counted_drop(self)
      class(counting_observer_t), intent(inout) :: self

      self%drops = self%drops + 1
   end subroutine counted_drop
end module test_newton
