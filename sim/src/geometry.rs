//! Geometry of the discrete world: headings, moves, field of view, line of sight, and how
//! much of a view an object fills.
//!
//! Conventions (AI2THOR): the floor is the x-z plane, y is up; heading 0 faces +z and heading 2
//! (90 degrees) faces +x; RotateRight adds 45 degrees. The camera is [`CAMERA_HEIGHT`] above
//! the floor; horizon 1 tilts it 30 degrees down.

use gman_core::Action;

use super::types::{CategoryProps, NUM_HEADINGS};

/// Grid step (metres).
pub const GRID: f32 = 0.25;
/// Camera height above the floor (AI2THOR agent centre 0.901 m + camera offset 0.675 m).
pub const CAMERA_HEIGHT: f32 = 1.576;
/// Field of view, horizontal and vertical (degrees); square frames as in the reference.
pub const FOV_DEG: f32 = 100.0;
/// Camera pitch of horizon 1 (degrees down).
pub const HORIZON_STEP_DEG: f32 = 30.0;
/// Visibility distance that counts for success (metres, measured to the object's footprint).
pub const VISIBILITY_DISTANCE: f32 = 1.0;
/// Objects farther than this (footprint distance) do not appear in the view's embedding.
pub const FEATURE_RANGE: f32 = 5.0;
/// Minimum apparent weight for an object to count as "in view" (PS target, features).
pub const IN_VIEW_MIN_WEIGHT: f32 = 0.05;
/// Sampling step of the line-of-sight test (metres).
const LOS_STEP: f32 = 0.05;
/// A stretch of blocked floor shorter than this on the ray is ignored (corner clipping).
const LOS_TOLERANCE: f32 = 0.3;

/// Grid step (dx, dz) of MoveAhead for a heading (diagonal headings move diagonally).
pub fn heading_step(heading: u8) -> (i32, i32) {
    const STEPS: [(i32, i32); NUM_HEADINGS] = [
        (0, 1),
        (1, 1),
        (1, 0),
        (1, -1),
        (0, -1),
        (-1, -1),
        (-1, 0),
        (-1, 1),
    ];
    STEPS[heading as usize % NUM_HEADINGS]
}

/// Unit vector (x, z) of a heading.
pub fn heading_dir(heading: u8) -> (f32, f32) {
    let a = (heading as f32 * 45.0).to_radians();
    (a.sin(), a.cos())
}

/// Pose change of a non-move action: (new heading, new horizon), or `None` for MoveAhead/Done.
pub fn turn(heading: u8, horizon: u8, action: Action) -> Option<(u8, u8)> {
    match action {
        Action::RotateLeft => Some((
            (heading + NUM_HEADINGS as u8 - 1) % NUM_HEADINGS as u8,
            horizon,
        )),
        Action::RotateRight => Some(((heading + 1) % NUM_HEADINGS as u8, horizon)),
        Action::LookUp => Some((heading, horizon.saturating_sub(1))),
        Action::LookDown => Some((heading, (horizon + 1).min(1))),
        Action::MoveAhead | Action::Done => None,
    }
}

/// Horizontal distance from a point to an object's footprint (centre distance minus radius).
pub fn footprint_distance(px: f32, pz: f32, obj: [f32; 3], props: &CategoryProps) -> f32 {
    let d = ((obj[0] - px).powi(2) + (obj[2] - pz).powi(2)).sqrt();
    (d - props.radius).max(0.0)
}

/// An axis-aligned bounding box (metres): the extent of an object of the `thor5` object
/// layout ([`crate::types::ObjectLayout`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Centre (x, y, z).
    pub center: [f32; 3],
    /// Edge lengths (x, y, z), non-negative.
    pub size: [f32; 3],
}

impl Aabb {
    /// The point of the box's floor rectangle (x-z) nearest to (px, pz).
    pub fn nearest_point(&self, px: f32, pz: f32) -> (f32, f32) {
        let (hx, hz) = (self.size[0] * 0.5, self.size[2] * 0.5);
        (
            px.clamp(self.center[0] - hx, self.center[0] + hx),
            pz.clamp(self.center[2] - hz, self.center[2] + hz),
        )
    }

    /// Horizontal distance from (px, pz) to the box's floor rectangle (0 inside it).
    pub fn horizontal_distance(&self, px: f32, pz: f32) -> f32 {
        let (nx, nz) = self.nearest_point(px, pz);
        ((nx - px).powi(2) + (nz - pz).powi(2)).sqrt()
    }

    /// The four corners (x, z) of the floor rectangle.
    fn corners(&self) -> [(f32, f32); 4] {
        let (hx, hz) = (self.size[0] * 0.5, self.size[2] * 0.5);
        let (cx, cz) = (self.center[0], self.center[2]);
        [
            (cx - hx, cz - hz),
            (cx - hx, cz + hz),
            (cx + hx, cz - hz),
            (cx + hx, cz + hz),
        ]
    }
}

/// Distance (degrees) from angle 0 to the interval [lo, hi] (degrees, lo <= hi), modulo 360.
fn angle_to_interval(lo: f32, hi: f32) -> f32 {
    [-360.0f32, 0.0, 360.0]
        .iter()
        .map(|k| {
            if (lo..=hi).contains(k) {
                0.0
            } else {
                (lo - k).abs().min((hi - k).abs())
            }
        })
        .fold(f32::INFINITY, f32::min)
}

/// Signed angle (degrees, -180..=180) of the direction (dx, dz) from the heading (hx, hz).
fn signed_angle(dx: f32, dz: f32, hx: f32, hz: f32) -> f32 {
    // Heading dir (hx, hz) = (sin a, cos a); positive angles turn towards +x from +z.
    (dx * hz - dz * hx).atan2(dx * hx + dz * hz).to_degrees()
}

/// [`appearance`] of an object with a bounding box (the `thor5` layout): the distance is to
/// the box's floor rectangle, and the object is in the field of view when any part of the box
/// is (its horizontal angular span from the corners, its vertical span from the top and bottom
/// at the nearest and farthest horizontal distances). The weight keeps the category's visual
/// size and the distance to the box centre, with the centrality of the box's nearest angles.
pub fn appearance_box(
    px: f32,
    pz: f32,
    heading: u8,
    horizon: u8,
    b: &Aabb,
    props: &CategoryProps,
) -> Appearance {
    let fd = b.horizontal_distance(px, pz);
    let half = FOV_DEG * 0.5;
    let (hx, hz) = heading_dir(heading);
    let corners = b.corners();
    // Horizontal: 0 when the agent stands inside the rectangle, else the angular span of the
    // corners around the direction to the centre (< 180 degrees from outside a convex box).
    let h_eff = if fd <= 0.0 {
        0.0
    } else {
        let (dcx, dcz) = (b.center[0] - px, b.center[2] - pz);
        let ac = signed_angle(dcx, dcz, hx, hz);
        let cs = dcx.hypot(dcz).max(1e-6);
        let (ux, uz) = (dcx / cs, dcz / cs);
        let (mut lo, mut hi) = (0.0f32, 0.0f32);
        for &(x, z) in &corners {
            let d = signed_angle(x - px, z - pz, ux, uz);
            lo = lo.min(d);
            hi = hi.max(d);
        }
        angle_to_interval(ac + lo, ac + hi)
    };
    // Vertical: the box's top and bottom seen from the nearest and farthest distances.
    let d_near = fd.max(1e-3);
    let d_far = corners
        .iter()
        .map(|&(x, z)| ((x - px).powi(2) + (z - pz).powi(2)).sqrt())
        .fold(0.0f32, f32::max)
        .max(d_near);
    let (bot, top) = (
        b.center[1] - b.size[1] * 0.5 - CAMERA_HEIGHT,
        b.center[1] + b.size[1] * 0.5 - CAMERA_HEIGHT,
    );
    let elev = |y: f32, d: f32| y.atan2(d).to_degrees();
    let lower = if bot < 0.0 {
        elev(bot, d_near)
    } else {
        elev(bot, d_far)
    };
    let upper = if top > 0.0 {
        elev(top, d_near)
    } else {
        elev(top, d_far)
    };
    let pitch = -(horizon as f32) * HORIZON_STEP_DEG;
    let v_eff = if (lower..=upper).contains(&pitch) {
        0.0
    } else {
        (lower - pitch).abs().min((upper - pitch).abs())
    };
    let in_fov = h_eff <= half && v_eff <= half;
    Appearance::seen(fd, in_fov, || {
        let dc = ((b.center[0] - px).powi(2) + (b.center[2] - pz).powi(2)).sqrt();
        (dc, b.center[1], props.size, h_eff / half, v_eff / half)
    })
}

/// How an object appears from a camera pose (ignoring occlusion).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Appearance {
    /// Horizontal distance to the footprint (metres).
    pub footprint_distance: f32,
    /// True if (part of) the object is inside the horizontal and vertical field of view.
    pub in_fov: bool,
    /// Share of the view the object fills, in [0, 1] (0 when outside the field of view).
    pub weight: f32,
}

impl Appearance {
    /// The appearance of an object at footprint distance `fd`: outside the field of view
    /// (`in_fov` false) no share of the view; inside it, `view()`'s `(dc, y, size, hc, vc)`
    /// (horizontal distance to the centre, the centre's height, the category's size, the
    /// angular offsets in half fields of view) give the share: the size over the 3-D
    /// distance (at least 0.2 m), at most 1, times the offsets' centrality.
    fn seen(fd: f32, in_fov: bool, view: impl FnOnce() -> (f32, f32, f32, f32, f32)) -> Self {
        if !in_fov {
            return Appearance {
                footprint_distance: fd,
                in_fov,
                weight: 0.0,
            };
        }
        let (dc, y, size, hc, vc) = view();
        let d3 = (dc * dc + (y - CAMERA_HEIGHT).powi(2)).sqrt().max(0.2);
        let centrality = (1.0 - 0.6 * hc * hc).max(0.0) * (1.0 - 0.6 * vc * vc).max(0.0);
        let weight = (0.8 * size / d3).min(1.0) * centrality;
        Appearance {
            footprint_distance: fd,
            in_fov,
            weight,
        }
    }
}

/// Where `obj` (centre, category props) appears from position (px, pz) with `heading`/`horizon`.
pub fn appearance(
    px: f32,
    pz: f32,
    heading: u8,
    horizon: u8,
    obj: [f32; 3],
    props: &CategoryProps,
) -> Appearance {
    let dx = obj[0] - px;
    let dz = obj[2] - pz;
    let dc = (dx * dx + dz * dz).sqrt();
    let fd = (dc - props.radius).max(0.0);
    let half = FOV_DEG * 0.5;
    // Angular half-extent of the footprint: an object is in view if any part of it is.
    let ext = if dc > 1e-3 {
        (props.radius / dc).min(1.0).asin().to_degrees()
    } else {
        90.0
    };
    let (hx, hz) = heading_dir(heading);
    let h_off = if dc > 1e-3 {
        let cos = ((dx * hx + dz * hz) / dc).clamp(-1.0, 1.0);
        cos.acos().to_degrees()
    } else {
        0.0
    };
    let elev = (obj[1] - CAMERA_HEIGHT).atan2(dc.max(1e-3)).to_degrees();
    let pitch = -(horizon as f32) * HORIZON_STEP_DEG;
    let v_off = (elev - pitch).abs();
    let in_fov = h_off <= half + ext && v_off <= half + ext;
    Appearance::seen(fd, in_fov, || {
        let hc = (h_off - ext).max(0.0) / half;
        let vc = (v_off - ext).max(0.0) / half;
        (dc, obj[1], props.size, hc, vc)
    })
}

/// Line of sight over the grid from (px, pz) to the object centre (ox, oz).
///
/// Rule: the ray is sampled every 5 cm; it is blocked when it crosses a stretch of
/// non-reachable floor at least 0.3 m long and then comes back onto reachable floor before
/// the object (something stands between the agent and the object). The final stretch into the
/// object's own furniture (counter, wall, table) never blocks.
pub fn line_of_sight(
    px: f32,
    pz: f32,
    ox: f32,
    oz: f32,
    reachable: impl Fn(f32, f32) -> bool,
) -> bool {
    let dx = ox - px;
    let dz = oz - pz;
    let len = (dx * dx + dz * dz).sqrt();
    let n = (len / LOS_STEP) as usize;
    let mut blocked_run = 0.0f32;
    let mut max_run = 0.0f32;
    for i in 1..n {
        let t = i as f32 * LOS_STEP / len;
        if reachable(px + t * dx, pz + t * dz) {
            max_run = max_run.max(blocked_run);
            blocked_run = 0.0;
            if max_run >= LOS_TOLERANCE {
                return false;
            }
        } else {
            blocked_run += LOS_STEP;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: CategoryProps = CategoryProps {
        height: 1.0,
        radius: 0.1,
        size: 0.5,
        instances: 1,
    };

    #[test]
    fn moves_and_turns() {
        assert_eq!(heading_step(0), (0, 1));
        assert_eq!(heading_step(2), (1, 0));
        assert_eq!(heading_step(5), (-1, -1));
        assert_eq!(turn(0, 0, Action::RotateLeft), Some((7, 0)));
        assert_eq!(turn(7, 0, Action::RotateRight), Some((0, 0)));
        assert_eq!(turn(3, 0, Action::LookUp), Some((3, 0)));
        assert_eq!(turn(3, 0, Action::LookDown), Some((3, 1)));
        assert_eq!(turn(3, 1, Action::LookDown), Some((3, 1)));
        assert_eq!(turn(3, 1, Action::LookUp), Some((3, 0)));
    }

    #[test]
    fn fov_front_and_back() {
        let front = appearance(0.0, 0.0, 0, 0, [0.0, 1.0, 1.0], &P);
        assert!(front.in_fov && front.weight > 0.0);
        let back = appearance(0.0, 0.0, 4, 0, [0.0, 1.0, 1.0], &P);
        assert!(!back.in_fov && back.weight == 0.0);
        // 60 degrees off-axis: outside a 100 degree field of view.
        let a = 60f32.to_radians();
        let side = appearance(0.0, 0.0, 0, 0, [2.0 * a.sin(), 1.0, 2.0 * a.cos()], &P);
        assert!(!side.in_fov);
        // An object on the floor right in front is only seen when looking down.
        let floor = [0.0, 0.05, 0.8];
        assert!(!appearance(0.0, 0.0, 0, 0, floor, &P).in_fov);
        assert!(appearance(0.0, 0.0, 0, 1, floor, &P).in_fov);
    }

    #[test]
    fn boxes_are_seen_by_their_nearest_part() {
        // A 2 m box centred 1.6 m ahead: its near face is 0.6 m away, within the 1 m
        // visibility distance, while its centre is not.
        let b = Aabb {
            center: [0.0, 0.9, 1.6],
            size: [2.0, 1.8, 2.0],
        };
        let a = appearance_box(0.0, 0.0, 0, 0, &b, &P);
        assert!(a.in_fov && a.weight > 0.0);
        assert!((a.footprint_distance - 0.6).abs() < 1e-6);
        assert!((b.horizontal_distance(3.0, 1.6) - 2.0).abs() < 1e-6);
        assert_eq!(b.horizontal_distance(0.5, 1.0), 0.0);
        // Behind the agent: out of view; turned around: in view.
        assert!(!appearance_box(0.0, 0.0, 4, 0, &b, &P).in_fov);
        // A wide box whose centre is 70 degrees off-axis still shows its near corner.
        let side = Aabb {
            center: [2.0, 1.0, 0.73],
            size: [0.2, 0.2, 2.4],
        };
        assert!(!appearance(0.0, 0.0, 0, 0, side.center, &P).in_fov);
        assert!(appearance_box(0.0, 0.0, 0, 0, &side, &P).in_fov);
    }

    #[test]
    fn los_blocked_by_obstacle_between() {
        // Free floor except a wall strip at 1.0 <= z < 1.5.
        let free = |_x: f32, z: f32| !(1.0..1.5).contains(&z);
        assert!(!line_of_sight(0.0, 0.0, 0.0, 3.0, free));
        assert!(line_of_sight(0.0, 0.0, 0.0, 0.9, free));
        // Object inside the wall strip itself: visible.
        assert!(line_of_sight(0.0, 0.0, 0.0, 1.3, free));
    }
}
