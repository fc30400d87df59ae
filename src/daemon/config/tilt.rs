//! A compass's tilt accelerometer (`tilt`: a 3-axis compass's heading is
//! compensated with it, a 2-axis one's is checked against it) and how a
//! 3-axis compass lies on it (`mag_axes`); a 2-axis sensor's field across
//! its turn (`out_of_plane`).

use super::*;
use crate::model::tilt::AxisMap;

impl Checker<'_> {
    /// A 3-axis magnetometer's `mag_axes`: how its axes lie on its tilt
    /// accelerometer's (`tilt`: whether it has one); the identity when not
    /// given.
    pub(super) fn check_mag_axes(
        &self,
        key: &str,
        mag_axes: Option<&str>,
        tilt: bool,
    ) -> Result<AxisMap, ConfigError> {
        Ok(match mag_axes {
            None => AxisMap::IDENTITY,
            Some(_) if !tilt => {
                return Err(self.error(
                    &format!("{key}.mag_axes"),
                    "`mag_axes` maps the magnetometer's axes onto its tilt accelerometer's: \
                     give `tilt` (the 3-axis accelerometer sensor of the same source), or \
                     leave `mag_axes` out",
                ));
            }
            Some(text) => text.trim().parse::<AxisMap>().map_err(|_| {
                self.error(
                    &format!("{key}.mag_axes"),
                    format!(
                        "\"{}\" is not an axis mapping: give the magnetometer's signed axis \
                             along each of the accelerometer's x, y, z, each of x, y, z once \
                             (for example \"x,-z,y\"); `fieldcal heading --mag-axes auto` \
                             finds it from a tumble",
                        crate::io::excerpt(text.trim())
                    ),
                )
            })?,
        })
    }

    /// Resolves each sensor's `tilt`: another 3-axis accelerometer
    /// sensor of the same source.
    pub(super) fn link_tilts(
        &self,
        sensors: &mut [SensorConfig],
        pending: &[(usize, String)],
    ) -> Result<(), ConfigError> {
        for (i, name) in pending {
            let key = format!("sensor[{i}].tilt");
            let Some(me) = sensors.get(*i) else { continue };
            let found = sensors.iter().position(|s| &s.name == name);
            let Some(j) = found else {
                let names: Vec<&str> = sensors
                    .iter()
                    .filter(|s| s.sphere().is_some() && s.field == Field::Accel)
                    .map(|s| s.name.as_str())
                    .collect();
                return Err(self.error(
                    &key,
                    format!(
                        "no sensor named '{name}': give the 3-axis accelerometer sensor of source \
                         '{}' ({})",
                        me.source,
                        if names.is_empty() {
                            "the file has none: add one with field = \"accel\" and axes = \
                             [\"x\", \"y\", \"z\"]"
                                .to_string()
                        } else {
                            format!("the file has {}", names.join(", "))
                        }
                    ),
                ));
            };
            let other = &sensors[j];
            let problem = if j == *i {
                Some("a sensor cannot be its own tilt source".to_string())
            } else if other.sphere().is_none() {
                Some(format!(
                    "'{name}' is a 2-axis sensor: the tilt source must be a 3-axis accelerometer \
                     (axes = [\"x\", \"y\", \"z\"], field = \"accel\")"
                ))
            } else if other.field != Field::Accel {
                Some(format!(
                    "'{name}' measures {}: the tilt source must be an accelerometer (field = \"accel\")",
                    other.field.name()
                ))
            } else if other.source != me.source {
                Some(format!(
                    "'{name}' is a sensor of source '{}', not of '{}': the tilt source must be on \
                     the same board, read by the same source",
                    other.source, me.source
                ))
            } else if me.field != Field::Mag {
                Some(format!(
                    "a tilt-compensated or tilt-checked heading is a magnetometer's: this sensor \
                     measures {}",
                    me.field.name()
                ))
            } else {
                None
            };
            if let Some(problem) = problem {
                return Err(self.error(&key, problem));
            }
            let tilt = other.sphere().map(|t| TiltSource {
                sensor: name.clone(),
                stream: other.stream,
                axes: t.axes,
                columns: t.columns.clone(),
            });
            if let Some(me) = sensors.get_mut(*i) {
                if let Some(plane) = me.plane_mut() {
                    plane.tilt = tilt;
                } else if let Some(three) = me.sphere_mut() {
                    three.tilt = tilt;
                }
            }
        }
        Ok(())
    }

    /// A 3-axis sensor's `gyro`: "none", nothing (a device's compass with
    /// `tilt`: its tilt accelerometer's chip's gyro, when it has one), or
    /// three columns (a csv compass's, resolved by
    /// [`Checker::check_csv_gyro3`]). Only a magnetometer with `tilt` has a
    /// heading to check.
    pub(super) fn check_gyro3(
        &self,
        key: &str,
        s: &RawSensor,
        field: Field,
    ) -> Result<Gyro3Choice, ConfigError> {
        let k = format!("{key}.gyro");
        let columns = match &s.gyro {
            None => return Ok(Gyro3Choice::Auto),
            Some(RawGyro::One(name)) if name.trim() == "none" => return Ok(Gyro3Choice::Off),
            Some(RawGyro::One(name)) => {
                return Err(self.error(
                    &k,
                    format!(
                        "\"{}\": a 3-axis compass's heading is checked against a 3-axis gyro: a \
                         csv source's three columns, in the order of its tilt accelerometer's x, \
                         y, z (gyro = [\"gyro_x\", \"gyro_y\", \"gyro_z\"]), or a device's tilt \
                         accelerometer's chip's (leave gyro out); or \"none\"",
                        crate::io::excerpt(name.trim())
                    ),
                ));
            }
            Some(RawGyro::Three(columns)) => columns,
        };
        if field != Field::Mag {
            return Err(self.error(
                &k,
                format!(
                    "a gyro checks a compass's heading: a 3-axis {} sensor has none; leave gyro out",
                    field.name()
                ),
            ));
        }
        if s.tilt.is_none() {
            return Err(self.error(
                &k,
                "a 3-axis compass's heading, and its rate about the vertical, need its tilt \
                 accelerometer: give `tilt` too, or leave gyro out",
            ));
        }
        let names: Vec<String> = columns.iter().map(|c| c.trim().to_string()).collect();
        match <[String; 3]>::try_from(names) {
            Ok(names) => Ok(Gyro3Choice::Columns {
                names,
                units: GyroUnits::DegPerSecond,
            }),
            Err(names) => Err(self.error(
                &k,
                format!(
                    "{} columns given: give the gyro's three, in the order of the tilt \
                     accelerometer's x, y, z",
                    names.len()
                ),
            )),
        }
    }

    /// A csv 3-axis compass's gyro columns (`gyro`, checked by
    /// [`Checker::check_gyro3`]): each a column of a file of the source,
    /// three different ones, and their `gyro_units`.
    pub(super) fn check_csv_gyro3(
        &self,
        key: &str,
        gyro: &mut Gyro3Choice,
        units: Option<&str>,
        columns: &Columns<'_>,
    ) -> Result<(), ConfigError> {
        let units_key = format!("{key}.gyro_units");
        let Gyro3Choice::Columns { names, units: u } = gyro else {
            if units.is_some() {
                return Err(self.error(
                    &units_key,
                    "given without gyro columns: name them with gyro = [\"X\", \"Y\", \"Z\"], or \
                     leave gyro_units out",
                ));
            }
            // A csv compass's gyro is its columns or none.
            *gyro = Gyro3Choice::Off;
            return Ok(());
        };
        *u = self.check_gyro_units(&units_key, units)?;
        let keys: Vec<String> = (0..3).map(|i| format!("{key}.gyro[{i}]")).collect();
        let mut found = Vec::with_capacity(3);
        for (i, (name, k)) in names.iter().zip(&keys).enumerate() {
            if let Some(j) = names[..i].iter().position(|n| n == name) {
                return Err(self.error(
                    k,
                    format!("'{name}' is already gyro[{j}]: give three different columns"),
                ));
            }
            found.push(columns.find(k.clone(), name, "the gyro's rate about an axis")?);
        }
        // One file: its rows carry the three rates of one instant.
        columns.one_file(&found, &keys)?;
        Ok(())
    }

    /// A csv gyro's `gyro_units` (at `key`): deg/s (the default) or rad/s.
    pub(super) fn check_gyro_units(
        &self,
        key: &str,
        units: Option<&str>,
    ) -> Result<GyroUnits, ConfigError> {
        match units.map(str::trim) {
            None | Some("deg/s") => Ok(GyroUnits::DegPerSecond),
            Some("rad/s") => Ok(GyroUnits::RadPerSecond),
            Some(other) => Err(self.error(
                key,
                format!("\"{other}\" is not a unit of angular rate: give \"deg/s\" or \"rad/s\""),
            )),
        }
    }

    /// Gyro columns on a device's 3-axis compass (of a `src_kind` source).
    pub(super) fn refuse_gyro_columns(
        &self,
        key: &str,
        s: &RawSensor,
        src_kind: &str,
    ) -> Result<(), ConfigError> {
        if matches!(s.gyro, Some(RawGyro::Three(_))) {
            return Err(self.error(
                &format!("{key}.gyro"),
                format!(
                    "gyro columns are a csv source's: a {src_kind} source's 3-axis compass takes \
                     the gyro of its tilt accelerometer's chip (leave gyro out), or \"none\""
                ),
            ));
        }
        Ok(())
    }

    /// Three gyro columns or axes on a 2-axis sensor, whose gyro is one
    /// `what` ("column" or "axis").
    pub(super) fn gyro_three_on_plane(&self, key: &str, what: &str) -> ConfigError {
        self.error(
            &format!("{key}.gyro"),
            format!(
                "three gyro columns are a 3-axis compass's (with tilt): a 2-axis sensor's gyro \
                 is one {what}, the one it turns about, or \"none\""
            ),
        )
    }

    /// A csv 2-axis sensor's `out_of_plane`: a column of the file of its
    /// `axes`, not one of them.
    pub(super) fn check_csv_out_of_plane(
        &self,
        key: &str,
        given: Option<&str>,
        columns: &Columns<'_>,
        axes: &[(usize, String); 2],
    ) -> Result<Option<OutOfPlane>, ConfigError> {
        let Some(name) = given.map(str::trim) else {
            return Ok(None);
        };
        let k = format!("{key}.out_of_plane");
        if axes.iter().any(|(_, a)| a == name) {
            return Err(self.error(
                &k,
                format!(
                    "'{name}' is one of the axes that turn: give the column of the third \
                     axis, across the turn"
                ),
            ));
        }
        let found = columns.find(k.clone(), name, "the axis across the turn")?;
        columns.one_file(
            &[axes[0].clone(), found.clone()],
            &[format!("{key}.axes[0]"), k],
        )?;
        Ok(Some(OutOfPlane::Column(found.1)))
    }

    /// A device's 2-axis sensor's `out_of_plane`: "x", "y" or "z", not one
    /// of its `axes`.
    pub(super) fn check_axis_out_of_plane(
        &self,
        key: &str,
        given: Option<&str>,
        axes: [Axis; 2],
    ) -> Result<Option<OutOfPlane>, ConfigError> {
        let Some(text) = given.map(str::trim) else {
            return Ok(None);
        };
        let axis = match text {
            "x" => Some(Axis::X),
            "y" => Some(Axis::Y),
            "z" => Some(Axis::Z),
            _ => None,
        }
        .filter(|a| !axes.contains(a));
        let Some(axis) = axis else {
            let third = [Axis::X, Axis::Y, Axis::Z]
                .into_iter()
                .find(|a| !axes.contains(a))
                .unwrap_or(Axis::Z);
            return Err(self.error(
                &format!("{key}.out_of_plane"),
                format!(
                    "\"{}\" is not the axis across the turn: give \"{}\", the axis of the \
                     sensor's field that is not in axes",
                    crate::io::excerpt(text),
                    third.name()
                ),
            ));
        };
        Ok(Some(OutOfPlane::Axis(axis)))
    }
}

/// Each 3-axis compass's gyro left to its tilt accelerometer's chip
/// ([`Gyro3Choice::Auto`]): that chip's gyro, in the accelerometer's
/// axes, when its stream carries one with a known scale; else none.
pub(super) fn link_gyros3(sensors: &mut [SensorConfig], checked: &CheckedSources) {
    for sensor in sensors.iter_mut() {
        let source = sensor.source.clone();
        let Some(three) = sensor.sphere_mut() else {
            continue;
        };
        if three.gyro != Gyro3Choice::Auto {
            continue;
        }
        let desc = three
            .tilt
            .as_ref()
            .filter(|t| t.columns.is_none())
            .and_then(|t| {
                let streams = checked.streams.get(*checked.index.get(&source)?)?;
                let desc = streams.iter().find(|d| d.id == t.stream)?;
                let lsb = sensors::gyro_lsb_per_deg_s(*desc)?;
                desc.fields()
                    .contains(&Field::Gyro)
                    .then_some((t.stream, t.axes, lsb))
            });
        three.gyro = match desc {
            Some((stream, axes, lsb_per_deg_s)) => Gyro3Choice::Chip {
                stream,
                axes,
                lsb_per_deg_s,
            },
            None => Gyro3Choice::Off,
        };
    }
}
