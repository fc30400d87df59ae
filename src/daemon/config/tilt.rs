//! A 3-axis compass's tilt accelerometer (`tilt`) and how the compass
//! lies on it (`mag_axes`).

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
}
