//! The lasers' ray casts: a uniform grid over the floor plan, each cell listing the colliders
//! whose boxes reach into it, walked along a beam's plan projection cell by cell (the
//! traversal of Amanatides and Woo, "A fast voxel traversal algorithm for ray tracing",
//! Eurographics 1987) until no nearer surface can come.
//!
//! A laser's beams are long and nearly horizontal, and a building is a plan of thin walls: a
//! beam crosses few cells of a plan grid, each holding a few walls, where rapier's query
//! pipeline descends a tree of every collider's box for each beam (three quarters of an
//! office run's time went there; in an open hall of few colliders the tree is as fast). What
//! a beam hits is decided by the same call rapier
//! makes on each candidate (`Shape::cast_ray` at the collider's pose, solid), so the
//! distance of the first hit is the same to the bit; only between two surfaces at exactly the
//! same distance may the one reported differ (rapier's choice follows its tree's order).
//!
//! Colliders on fixed bodies are binned once; those on moving bodies (objects pushed about,
//! agents, people) are binned again before the first beam of each physics step.

use crate::lidar::BeamHit;
use glam::Vec3;
use rapier3d::parry::bounding_volume::Aabb;
use rapier3d::prelude::*;
use std::collections::HashMap;

/// Cells per fixed collider: the grid's cells are squares of the side that gives the plan
/// this many cells for each fixed collider (the usual rule for a uniform grid, cells in
/// proportion to the objects), so that a dense plan gets small cells and an open hall large
/// ones. Measured with `futago bench sensors` over the shipped worlds' 1 m to 3 m best sides
/// (office 1.5 m, hall 3 m, Intel's 0.5 m, corridor 1.5 m, lab 1.4 m), which this rule gives
/// within a few percent of their speed.
const CELLS_PER_COLLIDER: f32 = 1.5;
/// Bounds on a cell's side, m.
const MIN_CELL: f32 = 0.25;
const MAX_CELL: f32 = 4.0;
/// At most this many cells; a larger plan gets larger cells.
const MAX_CELLS: f32 = 262_144.0;
/// Every box is grown by this much before it is binned or tested, m: the traversal's and the
/// box tests' rounding (far below a millimetre at a laser's ranges) then never drops a
/// collider the beam reaches.
const PAD: f32 = 1e-3;

/// One collider the grid holds.
struct Entry {
    collider: ColliderHandle,
    /// What a beam that hits it hit.
    hit: BeamHit,
    /// Its world box, grown by [`PAD`] (refreshed each step for moving ones).
    lo: Vec3,
    hi: Vec3,
    /// Its shape's box in the collider's frame, turned into a (looser) world box each step
    /// for moving ones: a person's hull has tens of vertices to transform, its box eight.
    local: Aabb,
}

/// Cell lists in compressed rows: cell `c`'s entries are `items[start[c]..start[c + 1]]`.
#[derive(Default)]
struct Bins {
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Bins {
    /// The entries of cell `c`.
    fn cell(&self, c: usize) -> &[u32] {
        &self.items[self.start[c] as usize..self.start[c + 1] as usize]
    }
}

/// The plan grid of a world's colliders for laser ray casts (see the module's doc).
pub struct RayGrid {
    /// Plan corner of cell (0, 0), m.
    lo: [f32; 2],
    cell: f32,
    nx: i32,
    ny: i32,
    /// Fixed colliders first (`fixed` of them), then moving ones.
    entries: Vec<Entry>,
    fixed: usize,
    fixed_bins: Bins,
    moving_bins: Bins,
    /// Colliders whose box leaves the grid or covers much of it (floor and ceiling slabs):
    /// tested by every beam, fixed and moving ones.
    fixed_unbinned: Vec<u32>,
    moving_unbinned: Vec<u32>,
    /// The step whose poses `moving_bins` holds.
    binned_step: Option<u64>,
    /// Per entry, the last beam that tested it, so that a collider in many cells is cast
    /// against once a beam.
    tested: Vec<u32>,
    beam: u32,
}

/// The cells a box covers: its ranges along x and along y.
type CellBox = ((i64, i64), (i64, i64));

/// The cell range `[a, b]` along one axis that `[lo, hi]` covers, unclamped.
fn span(lo: f32, hi: f32, origin: f32, inv_cell: f32) -> (i64, i64) {
    (
        ((lo - origin) * inv_cell).floor() as i64,
        ((hi - origin) * inv_cell).floor() as i64,
    )
}

/// Whether the ray `origin + t dir` (`inv` holding `1 / dir`) meets the box for some `t` in
/// `[0, max]`.
fn meets(origin: Vec3, dir: Vec3, inv: Vec3, lo: Vec3, hi: Vec3, max: f32) -> bool {
    let (mut t0, mut t1) = (0.0f32, max);
    for k in 0..3 {
        let (o, d) = (origin[k], dir[k]);
        if d == 0.0 {
            if o < lo[k] || o > hi[k] {
                return false;
            }
        } else {
            let inv = inv[k];
            let (a, b) = ((lo[k] - o) * inv, (hi[k] - o) * inv);
            let (a, b) = if a <= b { (a, b) } else { (b, a) };
            t0 = t0.max(a);
            t1 = t1.min(b);
            if t0 > t1 {
                return false;
            }
        }
    }
    true
}

impl RayGrid {
    /// Bins every collider but those of `exclude` (the robot's body, which its own lasers do
    /// not see). `movers` names what a beam hitting a body's collider hit; any other body is
    /// [`BeamHit::Static`].
    pub fn new(
        bodies: &RigidBodySet,
        colliders: &ColliderSet,
        exclude: RigidBodyHandle,
        movers: &HashMap<RigidBodyHandle, BeamHit>,
    ) -> RayGrid {
        let mut fixed = Vec::new();
        let mut moving = Vec::new();
        for (h, co) in colliders.iter() {
            let parent = co.parent();
            if parent == Some(exclude) {
                continue;
            }
            let hit = parent
                .and_then(|b| movers.get(&b).copied())
                .unwrap_or(BeamHit::Static);
            let is_fixed = parent
                .and_then(|b| bodies.get(b))
                .is_none_or(|b| b.body_type().is_fixed());
            let (lo, hi) = grown(&co.compute_aabb());
            let e = Entry {
                collider: h,
                hit,
                lo,
                hi,
                local: co.shape().compute_local_aabb(),
            };
            if is_fixed {
                fixed.push(e);
            } else {
                moving.push(e);
            }
        }
        // The plan the fixed colliders cover (a world with none gets one cell at the origin;
        // an unbounded shape is left out, to be tested by every beam).
        let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for e in fixed
            .iter()
            .filter(|e| e.lo.is_finite() && e.hi.is_finite())
        {
            for k in 0..2 {
                lo[k] = lo[k].min(e.lo[k]);
                hi[k] = hi[k].max(e.hi[k]);
            }
        }
        if lo[0] > hi[0] {
            (lo, hi) = ([0.0; 2], [MAX_CELL; 2]);
        }
        let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
        let cell = (w * h / (CELLS_PER_COLLIDER * fixed.len().max(1) as f32))
            .sqrt()
            .clamp(MIN_CELL, MAX_CELL)
            .max((w * h / MAX_CELLS).sqrt());
        let nx = ((w / cell).ceil() as i32).max(1);
        let ny = ((h / cell).ceil() as i32).max(1);
        let n_fixed = fixed.len();
        let mut entries = fixed;
        entries.extend(moving);
        let mut grid = RayGrid {
            lo,
            cell,
            nx,
            ny,
            tested: vec![0; entries.len()],
            entries,
            fixed: n_fixed,
            fixed_bins: Bins::default(),
            moving_bins: Bins::default(),
            fixed_unbinned: Vec::new(),
            moving_unbinned: Vec::new(),
            binned_step: None,
            beam: 0,
        };
        let mut bins = Bins::default();
        let mut unbinned = Vec::new();
        grid.bin(0..n_fixed, &mut bins, &mut unbinned);
        grid.fixed_bins = bins;
        grid.fixed_unbinned = unbinned;
        grid.moving_bins.start = vec![0; (nx * ny) as usize + 1];
        grid
    }

    /// Fills `bins` with entries `range`, putting those whose box leaves the grid or covers
    /// more than a quarter of its cells in `unbinned`.
    fn bin(&self, range: std::ops::Range<usize>, bins: &mut Bins, unbinned: &mut Vec<u32>) {
        let cells = (self.nx * self.ny) as usize;
        let inv = 1.0 / self.cell;
        let spans: Vec<Option<CellBox>> = range
            .clone()
            .map(|i| {
                let e = &self.entries[i];
                let sx = span(e.lo.x, e.hi.x, self.lo[0], inv);
                let sy = span(e.lo.y, e.hi.y, self.lo[1], inv);
                let inside = sx.0 >= 0
                    && sy.0 >= 0
                    && sx.1 < self.nx as i64
                    && sy.1 < self.ny as i64
                    && e.lo.is_finite()
                    && e.hi.is_finite();
                let covered = (sx.1 - sx.0 + 1).saturating_mul(sy.1 - sy.0 + 1);
                (inside && covered <= (cells / 4).max(1) as i64).then_some((sx, sy))
            })
            .collect();
        bins.start.clear();
        bins.start.resize(cells + 1, 0);
        unbinned.clear();
        for (i, s) in range.clone().zip(&spans) {
            match s {
                Some((sx, sy)) => {
                    for y in sy.0..=sy.1 {
                        for x in sx.0..=sx.1 {
                            bins.start[(y * self.nx as i64 + x) as usize + 1] += 1;
                        }
                    }
                }
                None => unbinned.push(i as u32),
            }
        }
        for c in 0..cells {
            bins.start[c + 1] += bins.start[c];
        }
        bins.items.clear();
        bins.items.resize(bins.start[cells] as usize, 0);
        let mut fill = bins.start.clone();
        for (i, s) in range.zip(&spans) {
            if let Some((sx, sy)) = s {
                for y in sy.0..=sy.1 {
                    for x in sx.0..=sx.1 {
                        let c = (y * self.nx as i64 + x) as usize;
                        bins.items[fill[c] as usize] = i as u32;
                        fill[c] += 1;
                    }
                }
            }
        }
    }

    /// Bins the moving colliders at their poses now, once per physics step `step`.
    fn refresh(&mut self, colliders: &ColliderSet, step: u64) {
        if self.binned_step == Some(step) {
            return;
        }
        self.binned_step = Some(step);
        if self.entries.len() == self.fixed {
            return;
        }
        for e in &mut self.entries[self.fixed..] {
            (e.lo, e.hi) = match colliders.get(e.collider) {
                Some(co) => grown(&e.local.transform_by(co.position())),
                // Removed: a box no beam meets.
                None => (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            };
        }
        let mut bins = std::mem::take(&mut self.moving_bins);
        let mut unbinned = std::mem::take(&mut self.moving_unbinned);
        self.bin(self.fixed..self.entries.len(), &mut bins, &mut unbinned);
        self.moving_bins = bins;
        self.moving_unbinned = unbinned;
    }

    /// The first collider hit by the ray `origin + t dir`, `t` in `[0, max)`, at the colliders'
    /// poses of physics step `step`: its distance (in units of `dir`) and what it is. The
    /// same distance as rapier's `QueryPipeline::cast_ray` (solid) with the same colliders.
    pub fn cast(
        &mut self,
        colliders: &ColliderSet,
        step: u64,
        origin: Vec3,
        dir: Vec3,
        max: f32,
    ) -> Option<(f32, BeamHit)> {
        self.refresh(colliders, step);
        self.beam = self.beam.wrapping_add(1);
        if self.beam == 0 {
            self.tested.fill(0);
            self.beam = 1;
        }
        let mut best = Best {
            ray: Ray::new(origin, dir),
            inv: dir.recip(),
            t: max,
            hit: None,
        };
        for &i in self.fixed_unbinned.iter().chain(&self.moving_unbinned) {
            // Each is in no cell: no beam meets it twice.
            cast_entry(&self.entries[i as usize], colliders, &mut best);
        }
        // The ray's stretch over the grid's plan, [t0, t1].
        let (mut t0, mut t1) = (0.0f32, max);
        let hi = [
            self.lo[0] + self.nx as f32 * self.cell,
            self.lo[1] + self.ny as f32 * self.cell,
        ];
        for k in 0..2 {
            let (o, d) = (origin[k], dir[k]);
            if d == 0.0 {
                if o < self.lo[k] || o > hi[k] {
                    return best.found();
                }
            } else {
                let (a, b) = ((self.lo[k] - o) / d, (hi[k] - o) / d);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 > t1 || !(t0.is_finite() && t1.is_finite()) {
            return best.found();
        }
        let inv = 1.0 / self.cell;
        let cell_at = |k: usize, t: f32| -> i32 {
            let n = if k == 0 { self.nx } else { self.ny };
            (((origin[k] + t * dir[k] - self.lo[k]) * inv).floor() as i32).clamp(0, n - 1)
        };
        let mut c = [cell_at(0, t0), cell_at(1, t0)];
        let mut step_dir = [0i32; 2];
        let mut next = [f32::INFINITY; 2];
        let mut delta = [f32::INFINITY; 2];
        for k in 0..2 {
            let d = dir[k];
            if d > 0.0 {
                step_dir[k] = 1;
                next[k] = (self.lo[k] + (c[k] + 1) as f32 * self.cell - origin[k]) / d;
                delta[k] = self.cell / d;
            } else if d < 0.0 {
                step_dir[k] = -1;
                next[k] = (self.lo[k] + c[k] as f32 * self.cell - origin[k]) / d;
                delta[k] = -self.cell / d;
            }
        }
        let RayGrid {
            entries,
            tested,
            fixed_bins,
            moving_bins,
            beam,
            nx,
            ny,
            ..
        } = self;
        let (nx, ny, beam) = (*nx, *ny, *beam);
        let moving = !moving_bins.items.is_empty();
        let mut cell = (c[1] * nx + c[0]) as usize;
        let cell_step = [step_dir[0] as isize, step_dir[1] as isize * nx as isize];
        let mut enter = t0;
        let t1 = t1 * (1.0 + 1e-5) + PAD;
        loop {
            if enter > best.t * (1.0 + 1e-5) + PAD {
                break;
            }
            for &i in fixed_bins.cell(cell) {
                test(entries, tested, beam, colliders, i, &mut best);
            }
            if moving {
                for &i in moving_bins.cell(cell) {
                    test(entries, tested, beam, colliders, i, &mut best);
                }
            }
            let k = if next[0] < next[1] { 0 } else { 1 };
            enter = next[k];
            if enter > t1 {
                break;
            }
            c[k] += step_dir[k];
            if c[k] < 0 || c[k] >= if k == 0 { nx } else { ny } {
                break;
            }
            cell = cell.wrapping_add_signed(cell_step[k]);
            next[k] += delta[k];
        }
        best.found()
    }
}

/// Casts `best.ray` against entry `i` unless this beam (`beam`) has already.
#[inline(always)]
fn test(
    entries: &[Entry],
    tested: &mut [u32],
    beam: u32,
    colliders: &ColliderSet,
    i: u32,
    best: &mut Best,
) {
    let i = i as usize;
    if tested[i] == beam {
        return;
    }
    tested[i] = beam;
    cast_entry(&entries[i], colliders, best);
}

/// Casts `best.ray` against one entry, keeping the hit if it is the nearest yet.
fn cast_entry(e: &Entry, colliders: &ColliderSet, best: &mut Best) {
    if !meets(best.ray.origin, best.ray.dir, best.inv, e.lo, e.hi, best.t) {
        return;
    }
    let Some(co) = colliders.get(e.collider) else {
        return;
    };
    if let Some(t) = co.shape().cast_ray(co.position(), &best.ray, best.t, true)
        && t < best.t
    {
        best.t = t;
        best.hit = Some(e.hit);
    }
}

/// The nearest hit so far of one beam.
struct Best {
    ray: Ray,
    /// `1 / ray.dir`.
    inv: Vec3,
    t: f32,
    hit: Option<BeamHit>,
}

impl Best {
    fn found(&self) -> Option<(f32, BeamHit)> {
        self.hit.map(|h| (self.t, h))
    }
}

/// A collider's box grown by [`PAD`].
fn grown(b: &Aabb) -> (Vec3, Vec3) {
    (b.mins - Vec3::splat(PAD), b.maxs + Vec3::splat(PAD))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn v(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> Vec3 {
        Vec3::new(
            rng.random_range(lo..hi),
            rng.random_range(lo..hi),
            rng.random_range(lo..hi),
        )
    }

    fn rotation(rng: &mut ChaCha8Rng) -> Quat {
        Quat::from_euler(
            glam::EulerRot::ZYX,
            rng.random_range(-3.2..3.2),
            rng.random_range(-0.4..0.4),
            rng.random_range(-0.4..0.4),
        )
    }

    /// A cluttered world: walls, slabs, balls, hulls and cylinders on fixed bodies; people
    /// and an agent on kinematic bodies, some leaving the fixed colliders' plan; the robot.
    struct Scene {
        physics: PhysicsWorld,
        robot: RigidBodyHandle,
        moving: Vec<RigidBodyHandle>,
        movers: HashMap<RigidBodyHandle, BeamHit>,
    }

    fn scene(rng: &mut ChaCha8Rng) -> Scene {
        let mut p = PhysicsWorld::new();
        p.gravity = Vec3::ZERO;
        let fixed = |p: &mut PhysicsWorld, shape: SharedShape, pose: Pose| {
            let h = p
                .bodies
                .insert(RigidBodyBuilder::fixed().pose(pose).build());
            p.colliders
                .insert_with_parent(ColliderBuilder::new(shape).build(), h, &mut p.bodies);
        };
        // Floor and ceiling slabs over the whole plan.
        for z in [-0.05, 3.05] {
            fixed(
                &mut p,
                SharedShape::cuboid(10.0, 8.0, 0.05),
                Pose::from_translation(Vec3::new(10.0, 8.0, z)),
            );
        }
        for _ in 0..80 {
            let half = Vec3::new(
                rng.random_range(0.05..3.0),
                rng.random_range(0.05..0.3),
                rng.random_range(0.2..1.5),
            );
            let at = Vec3::new(
                rng.random_range(0.0..20.0),
                rng.random_range(0.0..16.0),
                half.z,
            );
            fixed(
                &mut p,
                SharedShape::cuboid(half.x, half.y, half.z),
                Pose::from_parts(at, rotation(rng)),
            );
        }
        for _ in 0..10 {
            let at = Vec3::new(
                rng.random_range(0.0..20.0),
                rng.random_range(0.0..16.0),
                0.5,
            );
            fixed(
                &mut p,
                SharedShape::ball(rng.random_range(0.05..0.6)),
                Pose::from_translation(at),
            );
            let pts: Vec<Vec3> = (0..12).map(|_| v(rng, -0.4, 0.4)).collect();
            let at = Vec3::new(
                rng.random_range(0.0..20.0),
                rng.random_range(0.0..16.0),
                0.3,
            );
            let hull = SharedShape::convex_hull(&pts).expect("random points have a hull");
            fixed(&mut p, hull, Pose::from_parts(at, rotation(rng)));
            let at = Vec3::new(
                rng.random_range(0.0..20.0),
                rng.random_range(0.0..16.0),
                0.4,
            );
            fixed(
                &mut p,
                SharedShape::cylinder(0.4, 0.2),
                Pose::from_parts(at, rotation(rng)),
            );
        }
        let mut movers = HashMap::new();
        let mut moving = Vec::new();
        for i in 0..25 {
            let at = Vec3::new(
                rng.random_range(-3.0..23.0),
                rng.random_range(-3.0..19.0),
                0.9,
            );
            let h = p.bodies.insert(
                RigidBodyBuilder::kinematic_position_based()
                    .pose(Pose::from_translation(at))
                    .build(),
            );
            for k in 0..2 {
                let col = ColliderBuilder::new(SharedShape::capsule_z(0.6, 0.15))
                    .translation(Vec3::new(0.0, 0.2 * k as f32, 0.0))
                    .build();
                p.colliders.insert_with_parent(col, h, &mut p.bodies);
            }
            movers.insert(
                h,
                if i == 0 {
                    BeamHit::Agent(7)
                } else {
                    BeamHit::Person(i)
                },
            );
            moving.push(h);
        }
        let robot = p.bodies.insert(
            RigidBodyBuilder::kinematic_position_based()
                .pose(Pose::from_translation(Vec3::new(5.0, 5.0, 0.3)))
                .build(),
        );
        p.colliders.insert_with_parent(
            ColliderBuilder::new(SharedShape::cylinder(0.3, 0.17)).build(),
            robot,
            &mut p.bodies,
        );
        p.step();
        Scene {
            physics: p,
            robot,
            moving,
            movers,
        }
    }

    /// Casts `n` random rays (origins inside and outside the plan, any direction, some along
    /// an axis or level) by the grid and by rapier's query pipeline; both must give the same
    /// distance to the bit and the same thing hit. Returns how many hit.
    fn agree(s: &Scene, grid: &mut RayGrid, step: u64, rng: &mut ChaCha8Rng, n: usize) -> usize {
        let p = &s.physics;
        let qp = p.query_pipeline_with_filter(QueryFilter::default().exclude_rigid_body(s.robot));
        let (mut hits, mut ties) = (0, 0);
        for i in 0..n {
            let origin = match i % 4 {
                0 => Vec3::new(
                    rng.random_range(-8.0..28.0),
                    rng.random_range(-8.0..24.0),
                    0.2,
                ),
                _ => Vec3::new(
                    rng.random_range(-2.0..22.0),
                    rng.random_range(-2.0..18.0),
                    rng.random_range(0.05..3.0),
                ),
            };
            let mut dir = v(rng, -1.0, 1.0);
            match i % 5 {
                0 => dir.z = 0.0,
                1 => dir[rng.random_range(0..3)] = 0.0,
                2 => dir = [Vec3::X, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z][i % 4],
                _ => {}
            }
            let Some(dir) = dir.try_normalize() else {
                continue;
            };
            let max = rng.random_range(0.1..40.0);
            let ray = Ray::new(origin, dir);
            let kind = |c: ColliderHandle| {
                let body = p.colliders[c].parent().expect("every collider has a body");
                s.movers.get(&body).copied().unwrap_or(BeamHit::Static)
            };
            let want = qp
                .cast_ray(&ray, max, true)
                .map(|(c, t)| (t.to_bits(), kind(c)));
            let got = grid
                .cast(&p.colliders, step, origin, dir, max)
                .map(|(t, h)| (t.to_bits(), h));
            let at = |hit: Option<(u32, BeamHit)>| hit.map(|h| h.0);
            assert_eq!(
                at(got),
                at(want),
                "ray {i} from {origin} along {dir} to {max} m"
            );
            if got != want {
                // Two surfaces at the same distance (the ray starts inside both, say):
                // either may be reported, but only one of them.
                let t = f32::from_bits(at(want).expect("both hit"));
                let tied: Vec<BeamHit> = p
                    .colliders
                    .iter()
                    .filter(|(_, co)| co.parent() != Some(s.robot))
                    .filter(|(_, co)| {
                        co.shape().cast_ray(co.position(), &ray, max, true) == Some(t)
                    })
                    .map(|(c, _)| kind(c))
                    .collect();
                assert!(
                    tied.contains(&got.unwrap().1) && tied.contains(&want.unwrap().1),
                    "ray {i}: {got:?} and {want:?}, tied {tied:?}"
                );
                ties += 1;
            }
            hits += want.is_some() as usize;
        }
        assert!(ties * 100 < n, "{ties} ties in {n} rays");
        hits
    }

    #[test]
    fn beams_hit_what_rapier_hits_at_the_same_distance() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut s = scene(&mut rng);
        let mut grid = RayGrid::new(&s.physics.bodies, &s.physics.colliders, s.robot, &s.movers);
        let hits = agree(&s, &mut grid, 1, &mut rng, 20_000);
        assert!(hits > 10_000 && hits < 19_000, "{hits} of 20000 rays hit");
        // The people walk (some out of the plan, some into it): the grid follows them.
        for _ in 0..3 {
            for &h in &s.moving {
                let at = s.physics.bodies[h].translation()
                    + Vec3::new(
                        rng.random_range(-2.0..2.0),
                        rng.random_range(-2.0..2.0),
                        0.0,
                    );
                s.physics.bodies[h].set_next_kinematic_position(Pose::from_translation(at));
            }
            s.physics.step();
        }
        agree(&s, &mut grid, 4, &mut rng, 20_000);
    }

    #[test]
    fn a_beam_stops_at_the_first_surface_of_a_corridor() {
        // A hand-computed case: two walls 2 m apart across x, a person between them.
        let mut p = PhysicsWorld::new();
        let wall = |p: &mut PhysicsWorld, x: f32| {
            let h = p.bodies.insert(
                RigidBodyBuilder::fixed()
                    .pose(Pose::from_translation(Vec3::new(x, 0.0, 1.0)))
                    .build(),
            );
            p.colliders.insert_with_parent(
                ColliderBuilder::new(SharedShape::cuboid(0.1, 5.0, 1.0)).build(),
                h,
                &mut p.bodies,
            );
        };
        wall(&mut p, 0.0);
        wall(&mut p, 2.0);
        let person = p.bodies.insert(
            RigidBodyBuilder::kinematic_position_based()
                .pose(Pose::from_translation(Vec3::new(1.0, 3.0, 1.0)))
                .build(),
        );
        p.colliders.insert_with_parent(
            ColliderBuilder::new(SharedShape::ball(0.25)).build(),
            person,
            &mut p.bodies,
        );
        let robot = p.bodies.insert(RigidBodyBuilder::dynamic().build());
        let movers = HashMap::from([(person, BeamHit::Person(0))]);
        let mut grid = RayGrid::new(&p.bodies, &p.colliders, robot, &movers);
        let cast = |grid: &mut RayGrid, o: Vec3, d: Vec3| grid.cast(&p.colliders, 0, o, d, 30.0);
        // From x = 0.5 east: the far wall's face at x = 1.9.
        let (t, h) = cast(&mut grid, Vec3::new(0.5, 0.0, 0.2), Vec3::X).unwrap();
        assert!((t - 1.4).abs() < 1e-6 && h == BeamHit::Static, "{t} {h:?}");
        // West: the near wall's face at x = 0.1.
        let (t, _) = cast(&mut grid, Vec3::new(0.5, 0.0, 0.2), Vec3::NEG_X).unwrap();
        assert!((t - 0.4).abs() < 1e-6, "{t}");
        // North along x = 1 at the person's height: the person's near side at y = 2.75.
        let (t, h) = cast(&mut grid, Vec3::new(1.0, 0.0, 1.0), Vec3::Y).unwrap();
        assert!(
            (t - 2.75).abs() < 1e-6 && h == BeamHit::Person(0),
            "{t} {h:?}"
        );
        // Under the walls' ends: nothing within range.
        assert_eq!(cast(&mut grid, Vec3::new(1.0, 0.0, 1.0), Vec3::NEG_Y), None);
    }
}
