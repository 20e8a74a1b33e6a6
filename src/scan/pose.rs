//! Where the sensor is: one pose, or a trajectory of timed poses interpolated at each
//! beam's own time (position linearly, rotation by slerp), which skews a moving scan as a
//! real one is skewed.
//!
//! A pose is a position and yaw, pitch, roll in degrees: `world_from_sensor =
//! Rz(yaw)·Ry(pitch)·Rx(roll)` (intrinsic z-y'-x'', right-handed: yaw turns +x toward +y
//! seen from above, positive pitch tips +x down toward -z, positive roll tips +y up).

use glam::{DQuat, DVec3, EulerRot};

/// A sensor pose in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// The sensor's origin (where every beam starts).
    pub position: DVec3,
    /// `world_from_sensor`: sensor axes (x forward, z up) into world axes.
    pub rotation: DQuat,
}

impl Pose {
    /// From a position and yaw, pitch, roll in degrees (see the module doc).
    pub fn new(position: DVec3, yaw_deg: f64, pitch_deg: f64, roll_deg: f64) -> Pose {
        Pose {
            position,
            rotation: DQuat::from_euler(
                EulerRot::ZYX,
                yaw_deg.to_radians(),
                pitch_deg.to_radians(),
                roll_deg.to_radians(),
            ),
        }
    }

    /// The identity pose at the world origin.
    pub const IDENTITY: Pose = Pose {
        position: DVec3::ZERO,
        rotation: DQuat::IDENTITY,
    };

    /// Parse `X,Y,Z[,YAW,PITCH,ROLL]` (degrees); `what` names the option in errors.
    pub fn parse(s: &str, what: &str) -> Result<Pose, String> {
        let v = parse_numbers(s, what)?;
        if v.len() != 3 && v.len() != 6 {
            return Err(format!(
                "{what}: expected X,Y,Z or X,Y,Z,YAW,PITCH,ROLL, got {} numbers in {s:?}",
                v.len()
            ));
        }
        let (yaw, pitch, roll) = if v.len() == 6 {
            (v[3], v[4], v[5])
        } else {
            (0.0, 0.0, 0.0)
        };
        check_position(DVec3::new(v[0], v[1], v[2]), what)?;
        Ok(Pose::new(DVec3::new(v[0], v[1], v[2]), yaw, pitch, roll))
    }
}

fn check_position(p: DVec3, what: &str) -> Result<(), String> {
    let max = crate::scene::MAX_COORD;
    if p.abs().max_element() > max {
        return Err(format!(
            "{what}: position [{}, {}, {}] is beyond {max:e}",
            p.x, p.y, p.z
        ));
    }
    Ok(())
}

fn parse_numbers(s: &str, what: &str) -> Result<Vec<f64>, String> {
    s.split(',')
        .enumerate()
        .map(|(i, x)| {
            let x = x.trim();
            match x.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(format!(
                    "{what}: value {} ({:?}) is not a finite number",
                    i + 1,
                    crate::scene::strict::shorten(x)
                )),
            }
        })
        .collect()
}

/// Timed poses, times strictly increasing: [`Trajectory::at`] interpolates between them.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    /// `(time in seconds, pose)`, at least one, times strictly increasing.
    pub poses: Vec<(f64, Pose)>,
}

impl Trajectory {
    /// Read the CSV: a header line `time,x,y,z,yaw,pitch,roll` (that order), then one pose
    /// a line, times in seconds (the scan's clock: 0 = the rotation's start) strictly
    /// increasing, angles in degrees. Blank lines and lines starting with `#` are skipped.
    /// Errors name the line (`trajectory line 3: ...`).
    pub fn from_csv(text: &str) -> Result<Trajectory, String> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let header = "time,x,y,z,yaw,pitch,roll";
        match lines.next() {
            Some((_, l)) if l.replace(' ', "") == header => {}
            Some((i, l)) => {
                return Err(format!(
                    "trajectory line {}: expected the header {header:?}, got {:?}",
                    i + 1,
                    crate::scene::strict::shorten(l)
                ));
            }
            None => return Err("trajectory: the file is empty".to_string()),
        }
        let mut poses: Vec<(f64, Pose)> = Vec::new();
        for (i, l) in lines {
            let what = format!("trajectory line {}", i + 1);
            let v = parse_numbers(l, &what)?;
            if v.len() != 7 {
                return Err(format!("{what}: expected 7 values, got {}", v.len()));
            }
            if let Some(&(prev, _)) = poses.last()
                && v[0] <= prev
            {
                return Err(format!(
                    "{what}: time {} must be after the previous line's {prev}",
                    v[0]
                ));
            }
            let p = DVec3::new(v[1], v[2], v[3]);
            check_position(p, &what)?;
            poses.push((v[0], Pose::new(p, v[4], v[5], v[6])));
        }
        if poses.is_empty() {
            return Err("trajectory: no poses after the header".to_string());
        }
        Ok(Trajectory { poses })
    }

    /// The pose at time `t`: position linear and rotation slerped between the two poses
    /// around `t`; before the first or after the last, that pose held.
    pub fn at(&self, t: f64) -> Pose {
        let p = &self.poses;
        let k = p.partition_point(|&(ti, _)| ti <= t);
        if k == 0 {
            return p[0].1;
        }
        if k == p.len() {
            return p[k - 1].1;
        }
        let ((t0, a), (t1, b)) = (p[k - 1], p[k]);
        // In halves: `t1 - t0` of finite times can overflow (-1e308 to 1e308 is inf, which
        // made every `s` 0); halving is exact, so other spans give the same bits.
        let s = (t / 2.0 - t0 / 2.0) / (t1 / 2.0 - t0 / 2.0);
        Pose {
            position: a.position.lerp(b.position, s),
            // glam's slerp takes the shorter arc (it flips b when a·b < 0).
            rotation: a.rotation.slerp(b.rotation, s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_turns_x_toward_y_and_pitch_tips_x_down() {
        let p = Pose::new(DVec3::ZERO, 90.0, 0.0, 0.0);
        assert!((p.rotation * DVec3::X - DVec3::Y).length() < 1e-15);
        let p = Pose::new(DVec3::ZERO, 0.0, 30.0, 0.0);
        assert!((p.rotation * DVec3::X).z < -0.49);
    }

    #[test]
    fn trajectory_interpolates_and_names_bad_lines() {
        let t = Trajectory::from_csv("time,x,y,z,yaw,pitch,roll\n0,0,0,0,0,0,0\n1,2,0,0,90,0,0\n")
            .unwrap();
        let mid = t.at(0.5);
        assert_eq!(mid.position, DVec3::new(1.0, 0.0, 0.0));
        let x = mid.rotation * DVec3::X;
        assert!((x - DVec3::new(0.5f64.sqrt(), 0.5f64.sqrt(), 0.0)).length() < 1e-15);
        assert_eq!(t.at(5.0).position.x, 2.0);
        // Times whose span overflows f64 (2e308) still interpolate: the midpoint at 0.
        let wide = Trajectory::from_csv(
            "time,x,y,z,yaw,pitch,roll\n-1e308,0,0,0,0,0,0\n1e308,10,0,0,0,0,0",
        )
        .unwrap();
        assert_eq!(wide.at(0.0).position, DVec3::new(5.0, 0.0, 0.0));
        let e = Trajectory::from_csv("time,x,y,z,yaw,pitch,roll\n0,0,0,0,0,0,0\n0,1,0,0,0,0,0")
            .unwrap_err();
        assert_eq!(
            e,
            "trajectory line 3: time 0 must be after the previous line's 0"
        );
        let e = Trajectory::from_csv("time,x,y,z,yaw,pitch,roll\n0,0,zz,0,0,0,0").unwrap_err();
        assert_eq!(
            e,
            "trajectory line 2: value 3 (\"zz\") is not a finite number"
        );
    }
}
