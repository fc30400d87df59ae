//! A 3-axis compass's tilt accelerometer (`tilt`) and how the compass
//! lies on it (`mag_axes`); a 2-axis sensor's field across its turn
//! (`out_of_plane`).

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

    /// Resolves each 3-axis sensor's `tilt`: another 3-axis accelerometer
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
                    "a tilt-compensated heading is a magnetometer's: this sensor measures {}",
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
            if let Some(three) = sensors.get_mut(*i).and_then(SensorConfig::sphere_mut) {
                three.tilt = tilt;
            }
        }
        Ok(())
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
