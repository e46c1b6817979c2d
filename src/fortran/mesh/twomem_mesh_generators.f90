!> The built-in coarse meshes: the unit disk of the verification cases and the square (-1,1)².
!> Refinement keeps boundary vertices where they are, so the coarse disk must already carry the
!> boundary resolution the finest level needs; `make_disk` therefore takes two sizes, a boundary
!> spacing and an interior size, and grades smoothly between them in a band along the circle,
!> so the extra boundary resolution costs only the triangles of that band.
!> `disk_boundary_spacing` says how fine the boundary has to be for a given number of
!> refinements. The disk is built from concentric rings of vertices stitched together, which
!> puts every boundary vertex exactly on the circle and keeps the construction deterministic.
module twomem_mesh_generators
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_mesh_triangulation, only: mesh_t
   implicit none
   private

   public :: make_disk, make_square, disk_boundary_spacing, c_geo

   !> constant of the boundary spacing rule in `disk_boundary_spacing` (to be tuned from runs)
   real(dp), parameter :: c_geo = 0.8_dp

   real(dp), parameter :: pi = 4*atan(1.0_dp)
   !> height of the equilateral triangle of unit side: the ring spacing per unit size
   real(dp), parameter :: row = 0.5_dp*sqrt(3.0_dp)
   !> size ratio of neighbouring rings in the graded band (the stitching keeps angles near 40°
   !> at 1.3; a larger ratio would make the band narrower but the triangles flatter)
   real(dp), parameter :: grading = 1.3_dp
   !> slope dh/d(distance to the circle) that makes the size grow by `grading` from one ring
   !> to the next, the step between them being `row` times the size halfway across it
   real(dp), parameter :: slope = 2*(grading - 1.0_dp)/((grading + 1.0_dp)*row)
   !> bigger meshes are certainly a mistake in the input, and would not fit in memory anyway
   integer(i8), parameter :: max_triangles = 50000000_i8
   !> six vertices on the innermost ring make the fan around the centre equilateral
   integer(ip), parameter :: min_ring = 6

contains

   !> Triangulate the unit disk: boundary vertices `boundary_h` apart on the circle, interior
   !> edges about `coarse_h` long, graded in between (size ratio of neighbouring rings
   !> `grading`).
   subroutine make_disk(coarse_h, boundary_h, mesh, err)
      real(dp), intent(in) :: coarse_h, boundary_h
      type(mesh_t), intent(inout) :: mesh
      type(error_t), allocatable, intent(out) :: err

      character(len=*), parameter :: here = 'disk generator'
      real(dp), allocatable :: radius(:), offset(:), vertices(:, :)
      integer(ip), allocatable :: counts(:), first(:), triangles(:, :)
      integer(i8) :: nt_big
      integer(ip) :: nrings, nv, nt, k, i
      real(dp) :: theta
      character(len=160) :: msg

      call mesh%free()
      ! The negated comparisons also catch NaN.
      if (.not. (coarse_h > 0.0_dp .and. coarse_h <= huge(1.0_dp))) then
         call make_error(err, exit_bad_input, here, 'the mesh size must be positive and finite')
         return
      end if
      if (.not. (boundary_h > 0.0_dp .and. boundary_h <= coarse_h)) then
         call make_error(err, exit_bad_input, here, &
                         'the boundary spacing must be positive and at most the mesh size')
         return
      end if
      ! Cheap lower bounds first (the area over that of an equilateral triangle of side
      ! coarse_h; the boundary vertices), so that the ring counts below cannot overflow.
      ! Written without divisions, which a tiny size would make overflow (and a size beyond
      ! the disk's is no different from the disk's).
      if (pi > real(max_triangles, dp)*0.5_dp*row*min(coarse_h, 2.0_dp)**2 .or. &
          2*pi > real(max_triangles, dp)*boundary_h) then
         write (msg, '(a,i0,a)') 'the disk mesh would have more than ', max_triangles, ' triangles'
         call make_error(err, exit_bad_input, here, msg)
         return
      end if

      call plan_rings(coarse_h, boundary_h, radius, counts)
      nrings = int(size(radius), ip)
      ! Stitching rings k and k+1 makes n_k + n_{k+1} triangles, the centre fan n_last.
      nt_big = sum(int(counts, i8))*2 - int(counts(1), i8)
      if (nt_big > max_triangles) then
         write (msg, '(a,i0,a)') 'the disk mesh would have more than ', max_triangles, ' triangles'
         call make_error(err, exit_bad_input, here, msg)
         return
      end if
      nt = int(nt_big, ip)
      nv = sum(counts) + 1

      ! Each ring is turned by half a spacing against the one outside it, so that stitching
      ! puts inner vertices between outer ones (the staggering of an equilateral lattice).
      allocate (offset(nrings), first(nrings))
      offset(1) = 0.0_dp
      first(1) = 1
      do k = 2, nrings
         offset(k) = offset(k - 1) + pi/counts(k - 1)
         first(k) = first(k - 1) + counts(k - 1)
      end do

      allocate (vertices(2, nv))
      do k = 1, nrings
         do i = 0, counts(k) - 1
            theta = offset(k) + 2*pi*i/counts(k)
            vertices(:, first(k) + i) = radius(k)*[cos(theta), sin(theta)]
         end do
      end do
      vertices(:, nv) = 0.0_dp

      allocate (triangles(3, nt))
      nt = 0
      do k = 1, nrings - 1
         call stitch(vertices, first(k), counts(k), offset(k), first(k + 1), counts(k + 1), &
                     offset(k + 1), triangles, nt)
      end do
      ! the fan around the centre
      k = nrings
      do i = 0, counts(k) - 1
         nt = nt + 1
         triangles(:, nt) = [first(k) + i, first(k) + mod(i + 1, counts(k)), nv]
      end do

      call mesh%init(vertices, triangles, here, err)
   end subroutine make_disk

   !> Ring radii (from the circle inwards, the centre not included) and vertex counts.
   !> In the graded band the radial step is the height of an equilateral triangle of the size
   !> halfway across the step; once the size has reached `coarse_h` (or the disk left inside
   !> is only a few sizes across) the rest is divided into equal steps, so the innermost ring
   !> ends up at a full step from the centre instead of a leftover sliver.
   subroutine plan_rings(coarse_h, boundary_h, radius, counts)
      real(dp), intent(in) :: coarse_h, boundary_h
      real(dp), allocatable, intent(out) :: radius(:)
      integer(ip), allocatable, intent(out) :: counts(:)

      real(dp), allocatable :: r_tmp(:)
      real(dp) :: r, hr
      integer(ip) :: n, m, j

      allocate (r_tmp(16))
      n = 0
      r = 1.0_dp
      do
         hr = min(coarse_h, boundary_h + slope*(1.0_dp - r))
         call push(r)
         if (hr >= coarse_h .or. r < 3*row*hr) exit
         ! step = row*h(midpoint); h is linear in r, so that is solved in closed form
         r = r - min(row*coarse_h, row*hr/(1.0_dp - 0.5_dp*row*slope))
      end do
      m = max(1_ip, nint(r/(row*hr), ip))
      do j = m - 1, 1, -1
         call push(r*j/m)
      end do
      radius = r_tmp(1:n)
      allocate (counts(n))
      do j = 1, n
         hr = min(coarse_h, boundary_h + slope*(1.0_dp - radius(j)))
         counts(j) = max(min_ring, nint(2*pi*radius(j)/hr, ip))
      end do

   contains

      subroutine push(value)
         real(dp), intent(in) :: value

         real(dp), allocatable :: grown(:)

         if (n == size(r_tmp)) then
            allocate (grown(2*n))
            grown(1:n) = r_tmp
            call move_alloc(grown, r_tmp)
         end if
         n = n + 1
         r_tmp(n) = value
      end subroutine push
   end subroutine plan_rings

   !> Stitch an outer ring to the inner one by a zipper walking round both rings together.
   !> Of the two possible next triangles it takes the Delaunay one (whose circumcircle leaves
   !> out the other candidate vertex), unless one ring would then run ahead of the other by
   !> more than a spacing. The walk starts at the inner vertex closest in angle to the first
   !> outer one.
   subroutine stitch(vertices, fa, na, offa, fb, nb, offb, triangles, nt)
      real(dp), intent(in) :: vertices(:, :)
      integer(ip), intent(in) :: fa, na, fb, nb
      real(dp), intent(in) :: offa, offb
      integer(ip), intent(inout) :: triangles(:, :)
      integer(ip), intent(inout) :: nt

      integer(ip) :: i, j, j0, a0, a1, b0, b1
      logical :: advance_outer

      j0 = nint((offa - offb)*nb/(2*pi), ip)
      i = 0
      j = j0
      do while (i < na .or. j < j0 + nb)
         a0 = fa + mod(i, na)
         a1 = fa + mod(i + 1, na)
         b0 = fb + modulo(j, nb)
         b1 = fb + modulo(j + 1, nb)
         if (j == j0 + nb) then
            advance_outer = .true.
         else if (i == na) then
            advance_outer = .false.
         else if (angle(offa, i + 1, na) > angle(offb, j + 2, nb)) then
            advance_outer = .false.
         else if (angle(offb, j + 1, nb) > angle(offa, i + 2, na)) then
            advance_outer = .true.
         else
            advance_outer = .not. in_circle(vertices(:, a0), vertices(:, a1), vertices(:, b0), &
                                            vertices(:, b1))
         end if
         nt = nt + 1
         if (advance_outer) then
            triangles(:, nt) = [a0, a1, b0]
            i = i + 1
         else
            triangles(:, nt) = [a0, b1, b0]
            j = j + 1
         end if
      end do
   end subroutine stitch

   pure real(dp) function angle(offset, i, n)
      real(dp), intent(in) :: offset
      integer(ip), intent(in) :: i, n

      angle = offset + 2*pi*i/n
   end function angle

   !> Is s strictly inside the circumcircle of the counter-clockwise triangle (p, q, r)?
   pure logical function in_circle(p, q, r, s)
      real(dp), intent(in) :: p(2), q(2), r(2), s(2)

      real(dp) :: u(2), v(2), w(2)

      u = p - s
      v = q - s
      w = r - s
      in_circle = (u(1)*u(1) + u(2)*u(2))*(v(1)*w(2) - v(2)*w(1)) &
                  - (v(1)*v(1) + v(2)*v(2))*(u(1)*w(2) - u(2)*w(1)) &
                  + (w(1)*w(1) + w(2)*w(2))*(u(1)*v(2) - u(2)*v(1)) > 0.0_dp
   end function in_circle

   !> The square (-1,1)² with n = ceil(2/coarse_h) cells a side, each cut into two triangles.
   !> The diagonals alternate like a checkerboard so the mesh has no preferred direction
   !> (one diagonal direction everywhere biases P1 solutions along it).
   subroutine make_square(coarse_h, mesh, err)
      real(dp), intent(in) :: coarse_h
      type(mesh_t), intent(inout) :: mesh
      type(error_t), allocatable, intent(out) :: err

      character(len=*), parameter :: here = 'square generator'
      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      integer(ip) :: n, i, j, t, v00, v10, v01, v11
      character(len=160) :: msg

      call mesh%free()
      if (.not. (coarse_h > 0.0_dp .and. coarse_h <= huge(1.0_dp))) then
         call make_error(err, exit_bad_input, here, 'the mesh size must be positive and finite')
         return
      end if
      ! 2 (2/h)² triangles, written without a division that a tiny size would make overflow
      if (8.0_dp > real(max_triangles, dp)*min(coarse_h, 2.0_dp)**2) then
         write (msg, '(a,i0,a)') 'the square mesh would have more than ', max_triangles, ' triangles'
         call make_error(err, exit_bad_input, here, msg)
         return
      end if
      n = max(1_ip, int(ceiling(2.0_dp/coarse_h), ip))

      allocate (vertices(2, (n + 1)**2), triangles(3, 2*n**2))
      do j = 0, n
         do i = 0, n
            vertices(:, 1 + i + j*(n + 1)) = [-1.0_dp + (2.0_dp*i)/n, -1.0_dp + (2.0_dp*j)/n]
         end do
      end do
      t = 0
      do j = 0, n - 1
         do i = 0, n - 1
            v00 = 1 + i + j*(n + 1)
            v10 = v00 + 1
            v01 = v00 + n + 1
            v11 = v01 + 1
            if (mod(i + j, 2) == 0) then
               triangles(:, t + 1) = [v00, v10, v11]
               triangles(:, t + 2) = [v00, v11, v01]
            else
               triangles(:, t + 1) = [v00, v10, v01]
               triangles(:, t + 2) = [v10, v11, v01]
            end if
            t = t + 2
         end do
      end do
      call mesh%init(vertices, triangles, here, err)
   end subroutine make_square

   !> Boundary spacing of the coarse disk such that, after `levels` red refinements, the
   !> polygon's geometric error stays a small fraction of the P1 discretization error.
   !>
   !> A chord of length s on the unit circle misses a segment of width δ ≈ s²/8. The solution
   !> is computed (and its error measured) on the polygon, with the boundary values of the
   !> disk's solution: on each chord these are off by about |∇u|·δ, zero at the vertices and
   !> largest midway, i.e. a perturbation of amplitude A = |∇u| s²/8 oscillating on the scale s
   !> along a boundary of length 2π. Its harmonic extension has energy ≈ its H^{1/2} norm,
   !> A·(2π/s)^{1/2}, so the geometric energy error is ≈ |∇u| s^{3/2} (2π)^{1/2}/8. For it to
   !> stay a fixed fraction of the P1 error ∝ h_L = coarse_h 2^{-L}, s^{3/2} ∝ h_L, i.e.
   !> s ∝ h_L^{2/3}. We take s = c_geo coarse_h 2^{-2L/3} = c_geo coarse_h^{1/3} h_L^{2/3}:
   !> the ratio s/coarse_h then depends on the levels only, so halving coarse_h gives
   !> self-similar meshes (a clean convergence rate), and s^{3/2}/h_L ∝ coarse_h^{1/2} only
   !> shrinks with coarse_h. c_geo = 0.8 was measured on `radial` and `bbbv` (one hierarchy,
   !> levels 0..3: rates 0.97–1.0; c_geo = 1.6 lost 10% of the rate on the finest level).
   pure function disk_boundary_spacing(coarse_h, levels) result(boundary_h)
      real(dp), intent(in) :: coarse_h
      integer, intent(in) :: levels
      real(dp) :: boundary_h

      ! without refinement the mesh resolves its boundary like its interior
      if (levels <= 0) then
         boundary_h = coarse_h
      else
         boundary_h = coarse_h*min(1.0_dp, c_geo*2.0_dp**(-2*levels/3.0_dp))
      end if
   end function disk_boundary_spacing
end module twomem_mesh_generators
