//! Which surfaces a robot's camera can see at all from the floor it can reach: the
//! denominator of the camera's coverage, as the reachable floor is the footprint's.
//!
//! A depth camera mounted level at height `h` sees a point only between its nearest and
//! farthest valid depths, and only within half its vertical field of view of the optical
//! axis: a point at height `z` needs a depth of at least `|z - h| / tan(vfov / 2)`. From a
//! camera position a horizontal distance `d` from the point, turning the robot puts the point
//! anywhere across the image, at depths from `d cos(hfov / 2)` to `d`; the deepest reachable
//! depth, `min(d, far)`, sees the most of a wall's height. So a point of a wall is observable
//! when some reachable position of the camera has a clear line of sight to it on the map at
//! a horizontal distance `d` with `d ≥ near` and `d cos(hfov / 2) ≤ far`, and the greatest such
//! depth reaches its height. The Kinect of seed 000 (1.2–3.5 m, 43° vertical) sees the wall of
//! a 2 m corridor up to 1.8 m only by looking along it from 3.5 m, and never sees the faces of
//! a clutter block less than 1.2 m from the walls around it.
//!
//! Written for futago: a ray march on the occupancy grid from each wall point over the
//! half-plane its face looks into, cached per map cell and direction of the face.

use futago_msgs::grid::OccupancyGrid;
use rustc_hash::FxHashMap;
use std::cell::{Cell, RefCell};

/// A level camera on the robot, as far as what it can see is concerned.
#[derive(Debug, Clone, Copy)]
pub struct CameraReach {
    /// Height of the optical centre above the floor, m.
    pub height: f64,
    /// How far ahead of the robot's centre the camera sits, m.
    pub forward: f64,
    /// The valid depths, m.
    pub near: f64,
    pub far: f64,
    /// Half the horizontal and vertical fields of view, rad.
    pub half_hfov: f64,
    pub half_vfov: f64,
}

/// Directions of a face's normal told apart by the cache (its angle in this many bins).
const NORMAL_BINS: f64 = 64.0;

/// The surfaces observable from the reachable floor of a map.
pub struct Observability {
    /// Occupancy at the camera's height: what blocks its line of sight.
    sight: OccupancyGrid,
    /// Cells of `sight` the robot's centre can reach.
    reachable: Vec<bool>,
    camera: CameraReach,
    /// The greatest depth found per (cell in front of the face, direction bin), m; 0 for none.
    cache: RefCell<FxHashMap<(usize, i32), f64>>,
    /// The last normal asked about, with its length and direction bin: a face's samples
    /// all share one, which cost a square root, an arc tangent and a rounding each.
    last_normal: Cell<Option<([f64; 2], f64, i32)>>,
}

impl Observability {
    /// From `sight` (occupancy at the camera's height) and the cells of the same grid the
    /// robot's centre can reach.
    pub fn new(
        sight: OccupancyGrid,
        reachable: Vec<bool>,
        camera: CameraReach,
    ) -> Result<Observability, String> {
        if reachable.len() != sight.width * sight.height {
            return Err(format!(
                "the reachable cells ({}) do not match the sight map ({} × {})",
                reachable.len(),
                sight.width,
                sight.height
            ));
        }
        Ok(Observability {
            sight,
            reachable,
            camera,
            cache: RefCell::new(FxHashMap::default()),
            last_normal: Cell::new(None),
        })
    }

    /// Whether the point `p` of a face whose outward normal is `normal` (horizontal, any
    /// length) can be seen by the camera from some reachable pose.
    pub fn sees(&self, p: [f64; 3], normal: [f64; 2]) -> bool {
        let depth = self.depth(p, normal);
        depth > 0.0 && (p[2] - self.camera.height).abs() <= depth * self.camera.half_vfov.tan()
    }

    /// The greatest depth at which a reachable camera pose can see the wall point `p` (by its
    /// map cell in front of the face and the face's direction), m; 0 when none can.
    fn depth(&self, p: [f64; 3], normal: [f64; 2]) -> f64 {
        let (len, bin) = match self.last_normal.get() {
            Some((n, len, bin)) if n == normal => (len, bin),
            _ => {
                let len = normal[0].hypot(normal[1]);
                let angle = normal[1].atan2(normal[0]);
                let bin = (angle / std::f64::consts::TAU * NORMAL_BINS).round() as i32;
                self.last_normal.set(Some((normal, len, bin)));
                (len, bin)
            }
        };
        if len.is_nan() || len <= 1e-9 {
            return 0.0;
        }
        let g = &self.sight;
        // The cell just in front of the face.
        let probe = 0.5 * g.resolution;
        let front = [
            p[0] + normal[0] / len * probe,
            p[1] + normal[1] / len * probe,
        ];
        let Some((i, j)) = g.cell_of(front[0], front[1]) else {
            return 0.0;
        };
        let key = (j * g.width + i, bin);
        if let Some(&d) = self.cache.borrow().get(&key) {
            return d;
        }
        let axis = bin as f64 / NORMAL_BINS * std::f64::consts::TAU;
        let d = self.march([p[0], p[1]], axis);
        self.cache.borrow_mut().insert(key, d);
        d
    }

    /// Rays from `p` over the half-plane around `axis`, each to the first obstacle; the
    /// greatest usable depth of a reachable cell on any of them.
    fn march(&self, p: [f64; 2], axis: f64) -> f64 {
        let c = &self.camera;
        let g = &self.sight;
        let cos_h = c.half_hfov.cos().max(1e-6);
        // The farthest camera that can still bring the point within its far depth.
        let reach = c.far / cos_h + c.forward;
        let step = 0.5 * g.resolution;
        // Rays close enough that they are at most half a cell apart at the far end.
        let rays = ((std::f64::consts::PI * reach / step).ceil() as usize).clamp(8, 4096);
        // The wall's own cell, which the first steps may still be in.
        let own = 1.5 * g.resolution;
        let mut best: f64 = 0.0;
        // From the normal outwards, alternating sides: the depth is the greatest over every
        // ray, but the search ends at the first ray reaching the far depth, which one along
        // the normal most often does. The order changes how soon, not what is found.
        for m in 0..rays {
            let r = centre_out(m, rays);
            let a = axis - std::f64::consts::FRAC_PI_2
                + std::f64::consts::PI * (r as f64 + 0.5) / rays as f64;
            let (dx, dy) = (a.cos(), a.sin());
            let mut s = step;
            while s <= reach {
                let Some((i, j)) = g.cell_of(p[0] + dx * s, p[1] + dy * s) else {
                    break;
                };
                let k = j * g.width + i;
                if g.cells[k] >= futago_robot::geometry::grid::OCCUPIED {
                    if s > own {
                        break;
                    }
                } else if self.reachable[k] {
                    // The camera sits `forward` ahead of the centre, facing the point.
                    let d = s - c.forward;
                    if d >= c.near && d * cos_h <= c.far {
                        best = best.max(d.min(c.far));
                        if best >= c.far {
                            return best;
                        }
                    }
                }
                s += step;
            }
        }
        best
    }
}

/// The `m`-th of `n` indices taken from the middle outwards, alternating sides: `n / 2`,
/// one below, one above, and so on; every index below `n` once.
fn centre_out(m: usize, n: usize) -> usize {
    let mid = n / 2;
    if m.is_multiple_of(2) {
        mid + m / 2
    } else {
        mid - m.div_ceil(2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rays are taken from the middle outwards, each once, for odd and even counts.
    #[test]
    fn the_rays_are_each_taken_once_from_the_middle() {
        for n in 1..40 {
            let order: Vec<usize> = (0..n).map(|m| centre_out(m, n)).collect();
            let mut sorted = order.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..n).collect::<Vec<_>>(), "{n}: {order:?}");
            assert_eq!(order[0], n / 2);
        }
        assert_eq!(
            (0..5).map(|m| centre_out(m, 5)).collect::<Vec<_>>(),
            [2, 1, 3, 0, 4]
        );
    }

    /// Seed 000's Kinect: 0.42 m up, 0.1 m ahead, 1.2–3.5 m, 57° × 43°.
    fn kinect() -> CameraReach {
        CameraReach {
            height: 0.42,
            forward: 0.1,
            near: 1.2,
            far: 3.5,
            half_hfov: 28.5f64.to_radians(),
            half_vfov: 21.5f64.to_radians(),
        }
    }

    /// A `w` × `h` grid of 5 cm cells at the origin, free inside a one-cell wall, with the
    /// given cells reachable.
    fn room(w: usize, h: usize, reachable: impl Fn(usize, usize) -> bool) -> Observability {
        let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], w, h);
        let mut r = vec![false; w * h];
        for j in 0..h {
            for i in 0..w {
                let wall = j == 0 || j == h - 1 || i == 0 || i == w - 1;
                g.set(i, j, if wall { 100 } else { 0 });
                r[j * w + i] = !wall && reachable(i, j);
            }
        }
        Observability::new(g, r, kinect()).unwrap()
    }

    /// The west wall's inner face (x = 0.05 m) of a room 8 m long: its height up to
    /// 0.42 + 3.5 tan 21.5° = 1.78 m is seen from the robot 3.6 m away, not above it.
    #[test]
    fn a_wall_is_seen_up_to_the_height_the_far_depth_reaches() {
        let o = room(162, 42, |_, _| true);
        let top = 0.42 + 3.5 * 21.5f64.to_radians().tan();
        let west = |z: f64| o.sees([0.05, 1.0, z], [1.0, 0.0]);
        assert!(west(0.0) && west(1.0) && west(top - 0.01), "{top}");
        assert!(!west(top + 0.01));
        // Facing away from the room, the same point sees nothing.
        assert!(!o.sees([0.05, 1.0, 0.5], [-1.0, 0.0]));
    }

    /// In a corridor 0.2 m wide where the robot's centre reaches only to 1.5 m from the west
    /// wall's face, the camera is at most about 1.4 m from it, and sees it up to about
    /// 0.42 + 1.4 tan 21.5° = 0.97 m; reaching only to 1.2 m, never within its near depth.
    #[test]
    fn a_wall_the_robot_cannot_back_away_from_is_seen_only_low() {
        // Free cells: x from 0.05 m, y from 0.05 to 0.25 m; reachable up to x = 1.55 m.
        let o = room(162, 6, |i, _| i <= 30);
        let west = |z: f64| o.sees([0.05, 0.15, z], [1.0, 0.0]);
        assert!(west(0.3) && west(0.9));
        assert!(!west(1.05));
        let o = room(162, 6, |i, _| i <= 24);
        assert!(!o.sees([0.05, 0.15, 0.42], [1.0, 0.0]));
    }

    /// A wall behind another sees nothing through it: a partition 1 m in front of the west
    /// wall, from one side of the room to the other, with the robot beyond it.
    #[test]
    fn a_wall_hidden_behind_another_is_not_observable() {
        let mut o = room(162, 42, |i, _| i > 30);
        for j in 0..42 {
            o.sight.set(20, j, 100);
        }
        assert!(!o.sees([0.05, 1.0, 0.42], [1.0, 0.0]));
        // The partition's own far face is.
        assert!(o.sees([1.05, 1.0, 0.42], [1.0, 0.0]));
    }
}
