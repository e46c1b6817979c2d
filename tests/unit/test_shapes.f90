!> The shape classes' integrals behind the algebraic flux's P2 fields and patch data
!> (twomem_estimate_shapes: mono_psi_q, div_proj, p2_from_p2, p2_from_p1 and the children's
!> child_mono_psi_q, child_bary_psi_q, child_q_coarse) against direct integration on the actual
!> triangles of a refined disk, with a rule of higher degree than the code's and monomials
!> computed here: every triangle of every level, the point-reflected middle children included.
!> These class integrals stand in for integrals on triangles 2^l times smaller and possibly
!> reflected, so a wrong area scaling, reflection or child numbering shows up here.
module test_shapes
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_generators, only: make_disk
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t, triangle_class, n_p2
   use twomem_estimate_patch, only: on_opposite_edge
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   implicit none
   private

   public :: collect_shapes

   !> the integrals are O(area) with O(1) scaled monomials: round-off relative to the area
   real(dp), parameter :: tol = 100*epsilon(1.0_dp)

contains

   subroutine collect_shapes(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('monomial_integrals_scaled_and_reflected', test_mono_psi_q), &
               new_unittest('divergence_space_projection', test_div_proj), &
               new_unittest('p2_projection_from_children', test_children), &
               new_unittest('patch_data_on_children', test_children_patch_data), &
               new_unittest('opposite_edges_by_numbering', test_opposite_edges)]
   end subroutine collect_shapes

   !> ∫_K m_j ψ_i q_k on every triangle K of levels 0..2 against its class's mono_psi_q / ρ², for
   !> RT0 and RT1. On the reflected triangles the unreflected class's table must be far off, or
   !> this test could not see a wrong reflection.
   subroutine test_mono_psi_q(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(rt_space_t) :: space
      type(shape_classes_t) :: shapes
      type(quadrature_t) :: rule
      real(dp), allocatable :: direct(:, :, :)
      real(dp) :: v(2, 3), ratio, dev, gap
      integer :: order, l, cls, n_reflected
      integer(ip) :: t
      character(len=80) :: what

      call refined_disk(h, err)
      if (allocated(err)) return
      rule = triangle_rule(8)
      do order = 0, 1
         call space%init(order)
         call shapes%init(space, h, err)
         if (allocated(err)) return
         allocate (direct(space%n_div, n_p2, 3))
         dev = 0.0_dp
         gap = huge(1.0_dp)
         n_reflected = 0
         do l = 0, h%levels
            do t = 1, h%meshes(l)%nt
               call triangle_class(l, t, cls, ratio)
               v = h%meshes(l)%vertices(:, h%meshes(l)%triangles(:, t))
               call moments(rule, v, space%n_div, direct)
               dev = max(dev, maxval(abs(direct - shapes%mono_psi_q(:, :, :, cls)/ratio**2))/area(v))
               if (modulo(cls, 2) == 0) then
                  n_reflected = n_reflected + 1
                  gap = min(gap, maxval(abs(direct - shapes%mono_psi_q(:, :, :, cls - 1)/ratio**2))/area(v))
               end if
            end do
         end do
         write (what, '("RT",i0,": deviation ",es9.2,", reflection gap ",es9.2)') order, dev, gap
         call check(err, dev <= tol, 'class integrals = direct ones, '//trim(what))
         call check(err, n_reflected > 0 .and. gap > 1.0e-3_dp, 'reflected triangles checked, '//trim(what))
         ! the next space's shapes%init would clear a failure
         if (allocated(err)) return
         deallocate (direct)
      end do
   end subroutine test_mono_psi_q

   !> div_proj(:, j, i) of a triangle's class makes m_j ψ_i minus its expansion in the q_k
   !> orthogonal to every q_l on the triangle itself, on every triangle of levels 0..2.
   subroutine test_div_proj(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(rt_space_t) :: space
      type(shape_classes_t) :: shapes
      type(quadrature_t) :: rule
      real(dp), allocatable :: direct(:, :, :), gram(:, :)
      real(dp) :: v(2, 3), ratio, dev
      integer :: order, l, cls, i
      integer(ip) :: t
      character(len=60) :: what

      call refined_disk(h, err)
      if (allocated(err)) return
      rule = triangle_rule(8)
      do order = 0, 1
         call space%init(order)
         call shapes%init(space, h, err)
         if (allocated(err)) return
         allocate (direct(space%n_div, n_p2, 3), gram(n_p2, n_p2))
         dev = 0.0_dp
         do l = 0, h%levels
            do t = 1, h%meshes(l)%nt
               call triangle_class(l, t, cls, ratio)
               v = h%meshes(l)%vertices(:, h%meshes(l)%triangles(:, t))
               call moments(rule, v, space%n_div, direct)
               ! the q_k are the first n_div monomials
               gram = p2_gram(rule, v)
               do i = 1, 3
                  dev = max(dev, maxval(abs(direct(:, :, i) - matmul(gram(1:space%n_div, 1:space%n_div), &
                                                                     shapes%div_proj(:, :, i, cls))))/area(v))
               end do
            end do
         end do
         write (what, '("RT",i0,": deviation ",es9.2)') order, dev
         call check(err, dev <= tol, 'residual of the projection orthogonal to P_p, '//trim(what))
         if (allocated(err)) return
         deallocate (direct, gram)
      end do
   end subroutine test_div_proj

   !> p2_from_p2 and p2_from_p1 of a triangle's class, applied to the monomials and barycentric
   !> coordinates of its children in the refined mesh (numbered 4(t − 1) + c), give the P2
   !> projection on the triangle itself: the moments against its monomials agree, levels 0..1.
   subroutine test_children(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(rt_space_t) :: space
      type(shape_classes_t) :: shapes
      type(quadrature_t) :: rule
      real(dp) :: v(2, 3), vc(2, 3), ratio, dev, gram(n_p2, n_p2), m2(n_p2, n_p2), m1(n_p2, 3)
      integer :: l, cls, c, n_reflected
      integer(ip) :: t, child
      character(len=60) :: what

      call refined_disk(h, err)
      if (allocated(err)) return
      rule = triangle_rule(8)
      call space%init(1)
      call shapes%init(space, h, err)
      if (allocated(err)) return
      dev = 0.0_dp
      n_reflected = 0
      do l = 0, h%levels - 1
         do t = 1, h%meshes(l)%nt
            call triangle_class(l, t, cls, ratio)
            if (modulo(cls, 2) == 0) n_reflected = n_reflected + 1
            v = h%meshes(l)%vertices(:, h%meshes(l)%triangles(:, t))
            gram = p2_gram(rule, v)
            do c = 1, 4
               child = 4*(t - 1) + c
               vc = h%meshes(l + 1)%vertices(:, h%meshes(l + 1)%triangles(:, child))
               call child_moments(rule, v, vc, m2, m1)
               dev = max(dev, maxval(abs(m2 - matmul(gram, shapes%p2_from_p2(:, :, c, cls))))/area(v), &
                         maxval(abs(m1 - matmul(gram, shapes%p2_from_p1(:, :, c, cls))))/area(v))
            end do
         end do
      end do
      write (what, '("deviation ",es9.2)') dev
      call check(err, n_reflected > 0, 'reflected parents checked')
      call check(err, dev <= tol, 'children projected as on the mesh, '//trim(what))
   end subroutine test_children

   !> The children's patch data of a triangle's class against direct integrals over its children
   !> in the refined mesh, ψ_i the parent's hat function found from the parent's corners (not
   !> from refine_red's midpoints), levels 0..1, RT0 and RT1. The table of the wrong child
   !> (c + 1), a table of the wrong sign and, on reflected parents, the unreflected class's
   !> table must be far off, or this test could not see such mistakes. The reflection shows on
   !> one of the four children at least: the middle child shares its parent's barycentre, and
   !> its q_coarse does not change. With RT0 (q = 1) child_q_coarse is ∫ 1 over a child, the
   !> same for all four children and both reflections, and child_bary_psi_q, with no monomial
   !> in it, the same for both reflections: those comparisons are made with RT1 only.
   subroutine test_children_patch_data(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(rt_space_t) :: space
      type(shape_classes_t) :: shapes
      type(quadrature_t) :: rule
      real(dp), allocatable :: mono(:, :, :), bary(:, :, :), q_coarse(:, :)
      real(dp) :: v(2, 3), vc(2, 3), ratio, rc2, dev(3), wrong_child(3), wrong_reflection(3), reflection_here(3), wrong_sign, a
      integer :: order, l, cls, c, n_reflected, n_child, n_reflection
      integer(ip) :: t, child
      character(len=200) :: what

      call refined_disk(h, err)
      if (allocated(err)) return
      rule = triangle_rule(8)
      do order = 0, 1
         call space%init(order)
         call shapes%init(space, h, err)
         if (allocated(err)) return
         allocate (mono(space%n_div, n_p2, 3), bary(space%n_div, 3, 3), q_coarse(space%n_div, space%n_div))
         dev = 0.0_dp
         wrong_child = huge(1.0_dp)
         wrong_reflection = huge(1.0_dp)
         wrong_sign = huge(1.0_dp)
         n_reflected = 0
         do l = 0, h%levels - 1
            do t = 1, h%meshes(l)%nt
               call triangle_class(l, t, cls, ratio)
               ! the children's ratio
               rc2 = (2*ratio)**2
               v = h%meshes(l)%vertices(:, h%meshes(l)%triangles(:, t))
               if (modulo(cls, 2) == 0) n_reflected = n_reflected + 1
               reflection_here = 0.0_dp
               do c = 1, 4
                  child = 4*(t - 1) + c
                  vc = h%meshes(l + 1)%vertices(:, h%meshes(l + 1)%triangles(:, child))
                  call child_patch_moments(rule, v, vc, space%n_div, mono, bary, q_coarse)
                  a = area(vc)
                  associate (cm => shapes%child_mono_psi_q, cb => shapes%child_bary_psi_q, cq => shapes%child_q_coarse)
                     dev = max(dev, [maxval(abs(mono - cm(:, :, :, c, cls)/rc2)), maxval(abs(bary - cb(:, :, :, c, cls)/rc2)), &
                                     maxval(abs(q_coarse - cq(:, :, c, cls)/rc2))]/a)
                     wrong_child = min(wrong_child, [maxval(abs(mono - cm(:, :, :, modulo(c, 4) + 1, cls)/rc2)), &
                                                     maxval(abs(bary - cb(:, :, :, modulo(c, 4) + 1, cls)/rc2)), &
                                                     maxval(abs(q_coarse - cq(:, :, modulo(c, 4) + 1, cls)/rc2))]/a)
                     wrong_sign = min(wrong_sign, maxval(abs(mono + cm(:, :, :, c, cls)/rc2))/a)
                     if (modulo(cls, 2) == 0) then
                        reflection_here = max(reflection_here, [maxval(abs(mono - cm(:, :, :, c, cls - 1)/rc2)), &
                                                                maxval(abs(bary - cb(:, :, :, c, cls - 1)/rc2)), &
                                                                maxval(abs(q_coarse - cq(:, :, c, cls - 1)/rc2))]/a)
                     end if
                  end associate
               end do
               if (modulo(cls, 2) == 0) wrong_reflection = min(wrong_reflection, reflection_here)
            end do
         end do
         write (what, '("RT",i0,": deviations ",3es9.2,", wrong child ",3es9.2,", wrong reflection ",3es9.2, &
                       &", wrong sign ",es9.2)') order, dev, wrong_child, wrong_reflection, wrong_sign
         n_child = merge(2, 3, order == 0)
         n_reflection = merge(1, 3, order == 0)
         call check(err, all(dev <= tol), 'children''s class integrals = direct ones, '//trim(what))
         call check(err, n_reflected > 0 .and. all(wrong_child(1:n_child) > 1.0e-3_dp) .and. &
                    all(wrong_reflection(1:n_reflection) > 1.0e-3_dp) .and. wrong_sign > 1.0e-3_dp, &
                    'a wrong child, reflection or sign is seen, '//trim(what))
         if (allocated(err)) return
         deallocate (mono, bary, q_coarse)
      end do
   end subroutine test_children_patch_data

   ! ---- fixtures and direct integrals ----

   !> A disk refined twice: its coarse triangles are irregular, no two of them alike.
   !> on_opposite_edge, which reads refine_red's numbering, against the geometry it stands for:
   !> an edge lies on the (coarse) edge opposite a patch vertex a when neither of its end points
   !> is, or (refined) descends from, a; for every corner of every triangle of the disk's levels 1 and 2.
   subroutine test_opposite_edges(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      integer(ip) :: t, a, e, child
      integer :: corner, c, m
      logical :: geometric

      call refined_disk(h, err)
      if (allocated(err)) return
      associate (coarse => h%meshes(1), fine => h%meshes(2), parents => h%maps(2)%vertex_parents)
         do t = 1, coarse%nt
            do corner = 1, 3
               a = coarse%triangles(corner, t)
               do m = 1, 3
                  e = coarse%triangle_edges(m, t)
                  geometric = all(coarse%edges(:, e) /= a)
                  call check(err, on_opposite_edge(.false., corner, 1, m) .eqv. geometric, 'edge opposite a vertex')
               end do
               do c = 1, 4
                  child = 4*(t - 1) + c
                  do m = 1, 3
                     e = fine%triangle_edges(m, child)
                     geometric = all(parents(:, fine%edges(1, e)) /= a) .and. all(parents(:, fine%edges(2, e)) /= a)
                     call check(err, on_opposite_edge(.true., corner, c, m) .eqv. geometric, &
                                'child edge on the coarse edge opposite a vertex')
                  end do
               end do
            end do
         end do
      end associate
   end subroutine test_opposite_edges

   subroutine refined_disk(h, err)
      type(mesh_hierarchy_t), intent(out) :: h
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: coarse

      call make_disk(0.5_dp, 0.25_dp, coarse, err)
      if (allocated(err)) return
      call h%init(coarse, 2, err)
   end subroutine refined_disk

   pure real(dp) function area(v)
      real(dp), intent(in) :: v(2, 3)

      area = 0.5_dp*abs((v(1, 2) - v(1, 1))*(v(2, 3) - v(2, 1)) - (v(1, 3) - v(1, 1))*(v(2, 2) - v(2, 1)))
   end function area

   !> 1, ξ1, ξ2, ξ1², ξ1ξ2, ξ2² at x, ξ = (x − barycentre)/longest edge of the triangle v.
   pure function monomials(v, x) result(m)
      real(dp), intent(in) :: v(2, 3), x(2)
      real(dp) :: m(n_p2)

      real(dp) :: xi(2), longest

      longest = max(norm2(v(:, 1) - v(:, 2)), norm2(v(:, 2) - v(:, 3)), norm2(v(:, 3) - v(:, 1)))
      xi = (x - sum(v, dim=2)/3)/longest
      m = [1.0_dp, xi(1), xi(2), xi(1)**2, xi(1)*xi(2), xi(2)**2]
   end function monomials

   !> integral(k, j, i) = ∫ m_j λ_i q_k over the triangle v (q_k = m_k, k ≤ n_div).
   pure subroutine moments(rule, v, n_div, integral)
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: v(2, 3)
      integer, intent(in) :: n_div
      real(dp), intent(out) :: integral(:, :, :)

      real(dp) :: m(n_p2), w
      integer :: k, i, j

      integral = 0.0_dp
      do k = 1, rule%n
         m = monomials(v, matmul(v, rule%bary(:, k)))
         w = rule%weights(k)*area(v)
         do i = 1, 3
            do j = 1, n_p2
               integral(:, j, i) = integral(:, j, i) + w*m(j)*rule%bary(i, k)*m(1:n_div)
            end do
         end do
      end do
   end subroutine moments

   !> ∫ m_i m_j over the triangle v.
   pure function p2_gram(rule, v) result(gram)
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: v(2, 3)
      real(dp) :: gram(n_p2, n_p2)

      real(dp) :: m(n_p2)
      integer :: k, j

      gram = 0.0_dp
      do k = 1, rule%n
         m = monomials(v, matmul(v, rule%bary(:, k)))
         do j = 1, n_p2
            gram(:, j) = gram(:, j) + rule%weights(k)*area(v)*m*m(j)
         end do
      end do
   end function p2_gram

   !> Over the child vc of the triangle v: m2(:, j) = ∫ m_j^child m^v and m1(:, j) = ∫ λ_j^child m^v.
   pure subroutine child_moments(rule, v, vc, m2, m1)
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: v(2, 3), vc(2, 3)
      real(dp), intent(out) :: m2(n_p2, n_p2), m1(n_p2, 3)

      real(dp) :: x(2), m(n_p2), mc(n_p2), w
      integer :: k, j

      m2 = 0.0_dp
      m1 = 0.0_dp
      do k = 1, rule%n
         x = matmul(vc, rule%bary(:, k))
         w = rule%weights(k)*area(vc)
         m = monomials(v, x)
         mc = monomials(vc, x)
         do j = 1, n_p2
            m2(:, j) = m2(:, j) + w*mc(j)*m
         end do
         do j = 1, 3
            m1(:, j) = m1(:, j) + w*rule%bary(j, k)*m
         end do
      end do
   end subroutine child_moments

   !> Over the child vc of the triangle v, with λ_i the barycentric coordinates of v and q_k = m_k
   !> of the triangle named: mono(k, j, i) = ∫ m_j^vc λ_i q_k^vc, bary(k, j, i) = ∫ λ_j^vc λ_i
   !> q_k^vc and q_coarse(k, l) = ∫ q_l^v q_k^vc.
   pure subroutine child_patch_moments(rule, v, vc, n_div, mono, bary, q_coarse)
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: v(2, 3), vc(2, 3)
      integer, intent(in) :: n_div
      real(dp), intent(out) :: mono(:, :, :), bary(:, :, :), q_coarse(:, :)

      real(dp) :: x(2), m(n_p2), mc(n_p2), lambda(3), w
      integer :: k, i, j

      mono = 0.0_dp
      bary = 0.0_dp
      q_coarse = 0.0_dp
      do k = 1, rule%n
         x = matmul(vc, rule%bary(:, k))
         w = rule%weights(k)*area(vc)
         m = monomials(v, x)
         mc = monomials(vc, x)
         lambda = barycentric(v, x)
         do i = 1, 3
            do j = 1, n_p2
               mono(:, j, i) = mono(:, j, i) + w*mc(j)*lambda(i)*mc(1:n_div)
            end do
            do j = 1, 3
               bary(:, j, i) = bary(:, j, i) + w*rule%bary(j, k)*lambda(i)*mc(1:n_div)
            end do
         end do
         do j = 1, n_div
            q_coarse(:, j) = q_coarse(:, j) + w*m(j)*mc(1:n_div)
         end do
      end do
   end subroutine child_patch_moments

   !> The barycentric coordinates of x in the triangle v (Cramer's rule).
   pure function barycentric(v, x) result(lambda)
      real(dp), intent(in) :: v(2, 3), x(2)
      real(dp) :: lambda(3)

      real(dp) :: e2(2), e3(2), d(2), det

      e2 = v(:, 2) - v(:, 1)
      e3 = v(:, 3) - v(:, 1)
      d = x - v(:, 1)
      det = e2(1)*e3(2) - e2(2)*e3(1)
      lambda(2) = (d(1)*e3(2) - d(2)*e3(1))/det
      lambda(3) = (e2(1)*d(2) - e2(2)*d(1))/det
      lambda(1) = 1.0_dp - lambda(2) - lambda(3)
   end function barycentric
end module test_shapes
