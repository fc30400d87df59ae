//! `[[sensor]]`: which stream or columns a sensor reads, its model and
//! effects, rotation and limits, gyro, tilt and true north.

use super::*;
use crate::model::tilt::AxisMap;

/// A sensor's geometry, with the settings that geometry uses.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorGeometry {
    /// Two axes turned about the third: a rotation and the paper's model.
    Plane(PlaneConfig),
    /// Three axes (`axes = ["x", "y", "z"]`): sphere coverage and an
    /// ellipsoid.
    Sphere(Sensor3Config),
}

/// What a 2-axis `[[sensor]]` adds to [`SensorConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneConfig {
    /// The raw x and y of the paper's model, in that order; different.
    pub axes: [Axis; 2],
    /// The model's effects, in catalogue order (the paper's: offset, scale).
    pub effects: Vec<String>,
    pub rotation: RotationSettings,
    pub limits: LimitSettings,
    /// Where the heading check of each rotation takes its gyro from.
    pub gyro: GyroChoice,
    /// A sensor of a csv source: the two columns that turn (the raw x and
    /// y, in that order); then the sensor's `stream`, `field` and `axes`
    /// are unused (0, mag, x and y).
    pub columns: Option<[String; 2]>,
    /// What is done with each later rotation after a calibration is accepted.
    pub watch: WatchSettings,
    /// The field across the turn (`out_of_plane`), for the trust monitor.
    pub out_of_plane: Option<OutOfPlane>,
    /// The 3-axis accelerometer whose vertical tells the trust monitor how
    /// far the compass is tilted from the attitude it was calibrated in
    /// (`tilt`; resolved once every sensor is read).
    pub tilt: Option<TiltSource>,
}

/// Where a 2-axis sensor's field across its turn is read (`out_of_plane`):
/// the third axis of its chip, or a column of its file.
#[derive(Debug, Clone, PartialEq)]
pub enum OutOfPlane {
    Axis(Axis),
    Column(String),
}

/// What a 2-axis sensor does with each later rotation once calibrated
/// (`learn`, `on_stale`; see [`crate::model::watch`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WatchSettings {
    /// Refine the calibration with each rotation that agrees with it.
    pub learn: bool,
    pub on_stale: OnStale,
}

/// What a rotation that shows the calibration stale does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OnStale {
    /// Keep the calibration, and distrust every reading until the sensor is
    /// recalibrated.
    #[default]
    Warn,
    /// Accept the new fit in its place.
    Replace,
}

/// What a `[[sensor]]` with three axes adds to [`SensorConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor3Config {
    /// The three axes, in the order of the sensor's x, y, z.
    pub axes: [Axis; 3],
    pub model: crate::model::ellipsoid::Ellipsoid3Model,
    /// Raw counts per gauss (a magnetometer, `lsb_per_gauss`) or per g (an
    /// accelerometer, `lsb_per_g`), when configured.
    pub lsb_per_unit: Option<f64>,
    pub tilt: Option<TiltSource>,
    /// The gyro its tilt-compensated heading is checked against (a
    /// magnetometer with `tilt`).
    pub gyro: Gyro3Choice,
    /// How the magnetometer's axes lie on its tilt accelerometer's (the
    /// board's): `mag_axes`, as `fieldcal heading --mag-axes`; the
    /// identity when not given. Used for the heading and the dip only: the
    /// calibration and `corrected` stay in the magnetometer's own axes.
    pub mag_axes: AxisMap,
    /// What a later sphere that shows the calibration stale does.
    pub on_stale: OnStale,
    pub sphere: crate::model::sphere_buffer::SphereSettings,
    /// A sensor of a csv source: the columns of its x, y, z (then `axes`
    /// is x, y, z and unused).
    pub columns: Option<[String; 3]>,
}

/// A 3-axis compass's gyro, for the trust monitor's check of its
/// tilt-compensated heading ([`crate::model::gyro3`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Gyro3Choice {
    /// None: `gyro = "none"`, a sensor that is no compass with a tilt
    /// accelerometer, a csv compass that names no gyro columns, or a
    /// device whose tilt accelerometer's chip has no gyro.
    #[default]
    Off,
    /// Not given on a device's compass: its tilt accelerometer's chip's
    /// gyro, when it has one (resolved with the tilt, then `Chip` or `Off`).
    Auto,
    /// The gyro of the tilt accelerometer's chip: its stream, in the
    /// accelerometer's axes, `lsb_per_deg_s` counts per deg/s.
    Chip {
        stream: u8,
        axes: [Axis; 3],
        lsb_per_deg_s: f64,
    },
    /// Three columns of one file of a csv source, in the order of the tilt
    /// accelerometer's x, y, z.
    Columns {
        names: [String; 3],
        units: GyroUnits,
    },
}

/// The accelerometer a magnetometer's heading is tilt-compensated with:
/// another 3-axis sensor of the same source (`tilt = "<name>"`).
#[derive(Debug, Clone, PartialEq)]
pub struct TiltSource {
    pub sensor: String,
    pub stream: u8,
    pub axes: [Axis; 3],
    /// For a csv source: the accelerometer sensor's three columns.
    pub columns: Option<[String; 3]>,
}

impl TiltSource {
    /// The accelerometer in words, as a calibration keeps it: its sensor
    /// and its columns or axes ("level: acc_x,acc_y,acc_z").
    pub fn describe(&self) -> String {
        let axes = match &self.columns {
            Some(columns) => columns.join(","),
            None => self.axes.map(|a| a.name()).join(","),
        };
        format!("{}: {axes}", self.sensor)
    }
}

impl Gyro3Choice {
    /// The gyro in words, as a calibration keeps it, with the `mag_axes`
    /// its heading was read under: "columns gx,gy,gz in deg/s; mag_axes
    /// -x,-z,y".
    pub fn describe(&self, mag_axes: &AxisMap) -> String {
        let gyro = match self {
            Gyro3Choice::Chip {
                stream,
                axes,
                lsb_per_deg_s,
            } => format!(
                "stream {stream} axes {} at {lsb_per_deg_s} counts per deg/s",
                axes.map(|a| a.name()).join(",")
            ),
            Gyro3Choice::Columns { names, units } => format!(
                "columns {} in {}",
                names.join(","),
                match units {
                    GyroUnits::DegPerSecond => "deg/s",
                    GyroUnits::RadPerSecond => "rad/s",
                }
            ),
            Gyro3Choice::Off | Gyro3Choice::Auto => "none".to_string(),
        };
        format!("{gyro}; mag_axes {mag_axes}")
    }
}

impl SensorConfig {
    /// The 2-axis settings, if the sensor turns in a plane.
    pub fn plane(&self) -> Option<&PlaneConfig> {
        match &self.geometry {
            SensorGeometry::Plane(plane) => Some(plane),
            SensorGeometry::Sphere(_) => None,
        }
    }

    /// The 3-axis settings, if the sensor covers a sphere.
    pub fn sphere(&self) -> Option<&Sensor3Config> {
        match &self.geometry {
            SensorGeometry::Sphere(three) => Some(three),
            SensorGeometry::Plane(_) => None,
        }
    }

    /// [`SensorConfig::plane`], to change.
    pub fn plane_mut(&mut self) -> Option<&mut PlaneConfig> {
        match &mut self.geometry {
            SensorGeometry::Plane(plane) => Some(plane),
            SensorGeometry::Sphere(_) => None,
        }
    }

    /// [`SensorConfig::sphere`], to change.
    pub fn sphere_mut(&mut self) -> Option<&mut Sensor3Config> {
        match &mut self.geometry {
            SensorGeometry::Sphere(three) => Some(three),
            SensorGeometry::Plane(_) => None,
        }
    }

    /// The model's names: a plane's effects, or the pieces of a sphere's
    /// model name (`paper+cross-axis`: `paper`, `cross-axis`).
    pub fn effects(&self) -> Vec<String> {
        match &self.geometry {
            SensorGeometry::Plane(plane) => plane.effects.clone(),
            SensorGeometry::Sphere(three) => {
                three.model.name().split('+').map(String::from).collect()
            }
        }
    }
}

impl Checker<'_> {
    /// A sensor of a csv source: two columns of its file (or of one of its
    /// files), and optionally a gyro column; or three columns and a `field`,
    /// a 3-axis sensor. The keys of a device's sensor are refused by name.
    /// Returns the sensor and the name its `tilt` gives.
    pub(super) fn check_csv_sensor(
        &self,
        key: &str,
        s: RawSensor,
        source: &SourceConfig,
        layouts: &[CsvLayout],
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        let paths: &[PathBuf] = match &source.kind {
            SourceKind::Csv(csv) => &csv.files,
            _ => &[],
        };
        let file = paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(" or ");
        let src = &source.name;
        let columns = Columns {
            checker: self,
            layouts,
            paths,
            file: file.clone(),
        };
        if s.axes.len() == 3 {
            return self.check_csv_sensor3(key, s, &columns);
        }
        for (name, given) in [
            ("field", s.field.is_some()),
            ("chip", s.chip.is_some()),
            ("mag_axes", s.mag_axes.is_some()),
            ("lsb_per_gauss", s.lsb_per_gauss.is_some()),
            ("lsb_per_g", s.lsb_per_g.is_some()),
            ("sphere", s.sphere.is_some()),
            ("gyro_chip", s.gyro_chip.is_some()),
            ("gyro_lsb_per_deg_s", s.gyro_lsb_per_deg_s.is_some()),
        ] {
            if given {
                return Err(self.error(
                    &format!("{key}.{name}"),
                    format!(
                        "a sensor of csv source '{src}' has no `{name}`: it names two columns \
                         of {file} in axes (and a gyro column in gyro, with gyro_units){}",
                        if matches!(
                            name,
                            "field" | "mag_axes" | "lsb_per_gauss" | "lsb_per_g" | "sphere"
                        ) {
                            "; a 3-axis sensor names three columns in axes, with field"
                        } else {
                            ""
                        }
                    ),
                ));
            }
        }
        let axes = match s.axes.as_slice() {
            [a, b] if a.trim() == b.trim() => {
                return Err(self.error(
                    &format!("{key}.axes"),
                    format!(
                        "both axes are \"{}\": give the two columns that turn, two different \
                         columns of {file}",
                        a.trim()
                    ),
                ));
            }
            [a, b] => {
                let keys = [format!("{key}.axes[0]"), format!("{key}.axes[1]")];
                let found = [
                    columns.find(keys[0].clone(), a, "the axes that turn")?,
                    columns.find(keys[1].clone(), b, "the axes that turn")?,
                ];
                columns.one_file(&found, &keys)?;
                found
            }
            other => {
                return Err(self.error(
                    &format!("{key}.axes"),
                    format!(
                        "{} columns given: give exactly two different columns of {file} (the \
                         two axes that turn), or three with field = \"mag\" or \"accel\" for a \
                         3-axis sensor",
                        other.len()
                    ),
                ));
            }
        };
        let names = [axes[0].1.clone(), axes[1].1.clone()];
        let gyro = self.check_csv_gyro(key, &s, &columns, &names)?;
        let out_of_plane =
            self.check_csv_out_of_plane(key, s.out_of_plane.as_deref(), &columns, &axes)?;
        let effects = self.check_model(&format!("{key}.model"), s.model.as_ref())?;
        let plane = PlaneSensor {
            stream: 0,
            field: Field::Mag,
            axes: [Axis::X, Axis::Y],
            effects,
            gyro,
            columns: Some(names),
            north: None,
            out_of_plane,
        };
        let tilt = s.tilt.clone();
        Ok((self.plane_sensor(key, s, plane)?, tilt))
    }

    /// A 2-axis sensor: its `[sensor.rotation]` and `[sensor.limits]`
    /// checked, and the sensor built from what was checked before.
    pub(super) fn plane_sensor(
        &self,
        key: &str,
        s: RawSensor,
        plane: PlaneSensor,
    ) -> Result<SensorConfig, ConfigError> {
        if let Err(problem) = s.rotation.validate() {
            return Err(self.error(&format!("{key}.rotation"), problem));
        }
        if let Err(problem) = s.limits.validate() {
            return Err(self.error(&format!("{key}.limits"), problem));
        }
        Ok(SensorConfig {
            name: s.name,
            source: s.source,
            stream: plane.stream,
            field: plane.field,
            geometry: SensorGeometry::Plane(PlaneConfig {
                axes: plane.axes,
                effects: plane.effects,
                rotation: s.rotation,
                limits: s.limits,
                gyro: plane.gyro,
                columns: plane.columns,
                watch: WatchSettings {
                    learn: s.learn.unwrap_or(false),
                    on_stale: s.on_stale.unwrap_or_default(),
                },
                out_of_plane: plane.out_of_plane,
                // Resolved by link_tilts.
                tilt: None,
            }),
            north: plane.north,
        })
    }

    /// A csv sensor's gyro column (in any file of the source, which plays
    /// them on one clock; not one of `axes`) and its units, or why there
    /// is no heading check.
    fn check_csv_gyro(
        &self,
        key: &str,
        s: &RawSensor,
        columns: &Columns<'_>,
        axes: &[String; 2],
    ) -> Result<GyroChoice, ConfigError> {
        let units_key = format!("{key}.gyro_units");
        let units = self.check_gyro_units(&units_key, s.gyro_units.as_deref())?;
        if matches!(s.gyro, Some(RawGyro::Three(_))) {
            return Err(self.gyro_three_on_plane(key, "column"));
        }
        Ok(match s.gyro_one().map(str::trim) {
            None | Some("none") if s.gyro_units.is_some() => {
                return Err(self.error(
                    &units_key,
                    "given without a gyro column: name it with gyro = \"COLUMN\", or leave \
                     gyro_units out",
                ));
            }
            None => GyroChoice::Off(format!(
                "no heading check: name a gyro column of {} with gyro = \"COLUMN\"",
                columns.file
            )),
            Some("none") => {
                GyroChoice::Off("no heading check: gyro = \"none\" in the configuration".into())
            }
            Some(name) => {
                let gyro_key = format!("{key}.gyro");
                // Any file of the source: its rows are on the axes' clock.
                let (_, name) = columns.find(
                    gyro_key.clone(),
                    name,
                    "the angular rate about the turn's axis",
                )?;
                if axes.contains(&name) {
                    return Err(self.error(
                        &gyro_key,
                        format!(
                            "'{name}' is one of the two axes that turn: give the gyro column of \
                             the turn's axis, or \"none\""
                        ),
                    ));
                }
                GyroChoice::Column { name, units }
            }
        })
    }

    /// A 3-axis sensor of a csv source: three different columns of one of
    /// its files (the sensor's x, y, z), the `field` they measure (columns
    /// carry none), and the 3-axis keys of a device's sensor.
    pub(super) fn check_csv_sensor3(
        &self,
        key: &str,
        s: RawSensor,
        columns: &Columns<'_>,
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        let source_columns = columns;
        let file = &columns.file;
        if s.chip.is_some() {
            return Err(self.error(
                &format!("{key}.chip"),
                format!(
                    "a 3-axis sensor of csv source '{}' has no `chip`: it names three \
                     columns of {file} in axes, with field = \"mag\" or \"accel\"",
                    s.source
                ),
            ));
        }
        let Some(field) = s.field else {
            return Err(self.error(
                &format!("{key}.field"),
                "missing: three columns carry no field, so a 3-axis sensor of a csv source \
                 needs field = \"mag\" (a magnetometer) or \"accel\" (an accelerometer)",
            ));
        };
        let names: Vec<&str> = s.axes.iter().map(|a| a.trim()).collect();
        for j in 1..names.len() {
            if let Some(i) = names[..j].iter().position(|n| *n == names[j]) {
                return Err(self.error(
                    &format!("{key}.axes[{j}]"),
                    format!(
                        "'{}' is already axes[{i}]: give three different columns of {file}, the \
                         sensor's x, y, z in that order",
                        names[j]
                    ),
                ));
            }
        }
        let what = match field {
            Field::Accel => "the sensor's acceleration (x, y, z)",
            _ => "the sensor's field (x, y, z)",
        };
        let keys: Vec<String> = (0..3).map(|k| format!("{key}.axes[{k}]")).collect();
        let mut found = Vec::with_capacity(3);
        for (k, name) in keys.iter().zip(&names) {
            found.push(columns.find(k.clone(), name, what)?);
        }
        columns.one_file(&found, &keys)?;
        let columns = [found[0].1.clone(), found[1].1.clone(), found[2].1.clone()];
        let units = s.gyro_units.clone();
        let (mut sensor, tilt) =
            self.check_sensor3(key, s, field, 0, &[Axis::X, Axis::Y, Axis::Z], "")?;
        if let Some(three) = sensor.sphere_mut() {
            three.columns = Some(columns);
            self.check_csv_gyro3(key, &mut three.gyro, units.as_deref(), source_columns)?;
        }
        Ok((sensor, tilt))
    }

    /// `declination_deg` or `location` on a sensor that is no magnetometer.
    pub(super) fn north_not_magnetometer(
        &self,
        key: &str,
        location_given: bool,
        field: Field,
    ) -> ConfigError {
        let name = if location_given {
            "location"
        } else {
            "declination_deg"
        };
        self.error(
            &format!("{key}.{name}"),
            format!(
                "`{name}` is a magnetometer's: this sensor measures {}, whose heading owes \
                 nothing to the Earth's magnetic north; leave it out",
                field.name()
            ),
        )
    }

    /// A `[[sensor]]` with three axes: its 3-D settings, and the name its
    /// `tilt` gives (resolved by [`Checker::link_tilts`] once every sensor
    /// is read).
    pub(super) fn check_sensor3(
        &self,
        key: &str,
        s: RawSensor,
        field: Field,
        stream: u8,
        parsed: &[Axis],
        src_name: &str,
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        use crate::daemon::sensor3::Sensor3Config;
        use crate::model::ellipsoid::Ellipsoid3Model;
        let axes = [parsed[0], parsed[1], parsed[2]];
        if axes[0] == axes[1] || axes[0] == axes[2] || axes[1] == axes[2] {
            return Err(self.error(
                &format!("{key}.axes"),
                "an axis is given twice: a 3-axis sensor gives \"x\", \"y\", \"z\", each once \
                 (in the order of its x, y, z)",
            ));
        }
        if field == Field::Gyro {
            return Err(self.error(
                &format!("{key}.field"),
                "a gyro measures no constant field: a 3-axis sensor is \"mag\" or \"accel\"",
            ));
        }
        let gyro = self.check_gyro3(key, &s, field)?;
        for (name, given) in [
            ("gyro_chip", s.gyro_chip.is_some()),
            ("gyro_lsb_per_deg_s", s.gyro_lsb_per_deg_s.is_some()),
            ("out_of_plane", s.out_of_plane.is_some()),
            ("rotation", s.rotation != RotationSettings::default()),
            ("limits", s.limits != LimitSettings::default()),
        ] {
            if given {
                return Err(self.error(
                    &format!("{key}.{name}"),
                    format!(
                        "`{name}` is for a 2-axis sensor's rotation: a 3-axis sensor collects \
                         until its directions cover the sphere, set in [sensor.sphere] \
                         (min_samples, max_samples, max_rms)"
                    ),
                ));
            }
        }
        let model = match &s.model {
            None => Ellipsoid3Model::Full,
            Some(toml::Value::String(text)) => text
                .trim()
                .parse::<Ellipsoid3Model>()
                .map_err(|e| self.error(&format!("{key}.model"), e))?,
            Some(other) => {
                return Err(self.error(
                    &format!("{key}.model"),
                    format!(
                        "found {}: a 3-axis sensor's model is a string, \"offset\", \
                         \"offset+scale\" or \"offset+scale+cross-axis\" (the default)",
                        type_name(other)
                    ),
                ));
            }
        };
        let (unit_key, wrong_key, unit) = match field {
            Field::Accel => ("lsb_per_g", "lsb_per_gauss", s.lsb_per_g),
            _ => ("lsb_per_gauss", "lsb_per_g", s.lsb_per_gauss),
        };
        let wrong = match field {
            Field::Accel => s.lsb_per_gauss,
            _ => s.lsb_per_g,
        };
        if wrong.is_some() {
            return Err(self.error(
                &format!("{key}.{wrong_key}"),
                format!(
                    "a {} sensor's units are `{unit_key}`, not `{wrong_key}`",
                    field.name()
                ),
            ));
        }
        if let Some(u) = unit
            && !(u.is_finite() && u > 0.0 && u <= 1e9)
        {
            return Err(self.error(
                &format!("{key}.{unit_key}"),
                format!("must be a positive number of counts (at most 1e9), got {u}"),
            ));
        }
        if s.learn.is_some() {
            return Err(self.error(
                &format!("{key}.learn"),
                "a 3-axis sensor's later spheres are watched (`on_stale`) but not merged \
                 into its calibration: `learn` applies to 2-axis sensors; remove the key",
            ));
        }
        let sphere = s.sphere.unwrap_or_default();
        if let Err(problem) = sphere.validate() {
            return Err(self.error(&format!("{key}.sphere"), problem));
        }
        if sphere.still && field != Field::Accel {
            return Err(self.error(
                &format!("{key}.sphere.still"),
                format!(
                    "still poses are for an accelerometer (field = \"accel\"): a {} reads the \
                     same whether it moves or rests; tumble it through every direction and leave \
                     `still` out",
                    field.name()
                ),
            ));
        }
        let _ = src_name;
        let mag_axes = self.check_mag_axes(key, s.mag_axes.as_deref(), s.tilt.is_some())?;
        let three = Sensor3Config {
            axes,
            model,
            lsb_per_unit: unit,
            mag_axes,
            on_stale: s.on_stale.unwrap_or_default(),
            // Resolved by link_tilts.
            tilt: None,
            gyro,
            sphere,
            columns: None,
        };
        Ok((
            SensorConfig {
                name: s.name,
                source: s.source,
                stream,
                field,
                geometry: SensorGeometry::Sphere(three),
                north: None,
            },
            s.tilt,
        ))
    }

    pub(super) fn check_model(
        &self,
        key: &str,
        model: Option<&toml::Value>,
    ) -> Result<Vec<String>, ConfigError> {
        let mut names: Vec<(String, String)> = Vec::new(); // (key, name)
        match model {
            None => names.push((key.to_string(), "paper".into())),
            Some(toml::Value::String(s)) => {
                names.extend(
                    s.split('+')
                        .map(|n| (key.to_string(), n.trim().to_string())),
                );
            }
            Some(toml::Value::Array(items)) => {
                if items.is_empty() {
                    return Err(self.error(
                        key,
                        "an empty list: give \"paper\" or a list of effects such as \
                         [\"offset\", \"scale\"]",
                    ));
                }
                for (k, item) in items.iter().enumerate() {
                    let item_key = format!("{key}[{k}]");
                    match item {
                        toml::Value::String(s) => names.push((item_key, s.trim().to_string())),
                        other => {
                            return Err(self.error(
                                &item_key,
                                format!("found {}: effect names are strings", type_name(other)),
                            ));
                        }
                    }
                }
            }
            Some(other) => {
                return Err(self.error(
                    key,
                    format!(
                        "found {}: give \"paper\" or a list of effect names",
                        type_name(other)
                    ),
                ));
            }
        }
        let mut effects: Vec<Effect> = Vec::new();
        for (item_key, name) in &names {
            if name == "paper" {
                effects.extend(effects::PAPER);
                continue;
            }
            let effect: Effect = name
                .parse()
                .map_err(|problem| self.error(item_key, problem))?;
            if !effect.is_live() {
                return Err(self.error(
                    item_key,
                    format!(
                        "the effect '{effect}' cannot correct live readings: it needs the time base or a \
                         logged column at correction time; the daemon fits {}; analyse it offline with \
                         `fieldcal fit --effects {effect}` or `fieldcal diagnose`",
                        effects::live().iter().map(Effect::to_string).collect::<Vec<_>>().join(", ")
                    ),
                ));
            }
            effects.push(effect);
        }
        let missing: Vec<String> = effects::PAPER
            .iter()
            .filter(|e| !effects.contains(e))
            .map(Effect::to_string)
            .collect();
        if !missing.is_empty() {
            return Err(self.error(
                key,
                format!(
                    "the model lacks {}: every model is the paper's (offset, scale) plus \
                     effects, so include both, or write \"paper\"",
                    missing.join(" and ")
                ),
            ));
        }
        // Catalogue order, each once.
        effects.sort();
        effects.dedup();
        Ok(effects.iter().map(Effect::to_string).collect())
    }

    /// The gyro of a sensor's heading check: the keys `gyro`, `gyro_chip`
    /// and `gyro_lsb_per_deg_s` of `sensor[i]` (`key`).
    pub(super) fn check_gyro(
        &self,
        key: &str,
        s: &RawSensor,
        axes: [Axis; 2],
        own: StreamDesc,
        source: &str,
        streams: &[StreamDesc],
    ) -> Result<GyroChoice, ConfigError> {
        let axis_key = format!("{key}.gyro");
        if matches!(s.gyro, Some(RawGyro::Three(_))) {
            return Err(self.gyro_three_on_plane(key, "axis"));
        }
        let chosen = match s.gyro_one().map(str::trim) {
            None => None,
            Some("none") => {
                if s.gyro_chip.is_some() {
                    return Err(self.error(
                        &format!("{key}.gyro_chip"),
                        "given with gyro = \"none\": name the gyro axis, or leave gyro_chip out",
                    ));
                }
                return Ok(GyroChoice::Off(
                    "no heading check: gyro = \"none\" in the configuration".into(),
                ));
            }
            Some("x") => Some(Axis::X),
            Some("y") => Some(Axis::Y),
            Some("z") => Some(Axis::Z),
            Some(other) => {
                return Err(self.error(
                    &axis_key,
                    format!(
                        "\"{other}\" is not a gyro axis: give \"x\", \"y\" or \"z\" (the \
                         gyro axis the sensor turns about) or \"none\""
                    ),
                ));
            }
        };
        let stream = match s.gyro_chip.as_deref() {
            None => own,
            Some(text) => self.gyro_stream(&format!("{key}.gyro_chip"), text, source, streams)?,
        };
        let has_gyro = stream.fields().contains(&Field::Gyro);
        if !has_gyro {
            return match chosen {
                None => Ok(GyroChoice::Off(format!(
                    "no heading check: {} of source '{source}' has no gyro (give gyro_chip for \
                     another chip's)",
                    stream.describe()
                ))),
                Some(_) => Err(self.error(
                    &axis_key,
                    format!(
                        "{} of source '{source}' has no gyro: give gyro_chip = \"NAME\" for \
                         another chip's, or leave gyro out",
                        stream.describe()
                    ),
                )),
            };
        }
        let same_stream = stream.id == own.id;
        let axis = match chosen {
            Some(axis) if same_stream && axes.contains(&axis) => {
                return Err(self.error(
                    &axis_key,
                    format!(
                        "\"{}\" is one of the two axes that turn ({}, {}): the turn is about the \
                         third, give it, or \"none\"",
                        axis.name(),
                        axes[0].name(),
                        axes[1].name()
                    ),
                ));
            }
            Some(axis) => axis,
            None if !same_stream => {
                return Err(self.error(
                    &axis_key,
                    "missing: with gyro_chip, say which of its axes the sensor turns about \
                     (\"x\", \"y\" or \"z\"): chips are not always mounted alike",
                ));
            }
            None if s.field == Some(Field::Gyro) => {
                return Ok(GyroChoice::Off(
                    "no heading check: the sensor is itself the gyro".into(),
                ));
            }
            None => [Axis::X, Axis::Y, Axis::Z]
                .into_iter()
                .find(|a| !axes.contains(a))
                .unwrap_or(Axis::Z),
        };
        let lsb_key = format!("{key}.gyro_lsb_per_deg_s");
        let lsb_per_deg_s = match (s.gyro_lsb_per_deg_s, gyro_lsb_per_deg_s(stream)) {
            (Some(v), _) if v.is_finite() && v > 0.0 && v <= 1e6 => v,
            (Some(v), _) => {
                return Err(self.error(
                    &lsb_key,
                    format!("{v}: give the gyro's counts per degree/second, above 0 (at most 1e6)"),
                ));
            }
            (None, Some(v)) => v,
            (None, None) => {
                return Err(self.error(
                    &lsb_key,
                    format!(
                        "missing: the scale of the gyro of {} is not known; give its counts per \
                         degree/second",
                        stream.describe()
                    ),
                ));
            }
        };
        Ok(GyroChoice::Rate {
            stream: stream.id,
            axis,
            lsb_per_deg_s,
        })
    }

    /// The stream of the chip named by `gyro_chip` on a sensor's source.
    pub(super) fn gyro_stream(
        &self,
        key: &str,
        text: &str,
        source: &str,
        streams: &[StreamDesc],
    ) -> Result<StreamDesc, ConfigError> {
        let (want, address) = parse_chip(text).map_err(|problem| self.error(key, problem))?;
        let listed = streams
            .iter()
            .map(|s| s.describe())
            .collect::<Vec<_>>()
            .join(", ");
        let matches: Vec<StreamDesc> = streams
            .iter()
            .filter(|s| {
                s.chip
                    .is_some_and(|(c, a)| c == want && address.is_none_or(|w| w == a))
            })
            .copied()
            .collect();
        match matches.as_slice() {
            [one] if one.fields().contains(&Field::Gyro) => Ok(*one),
            [one] => Err(self.error(
                key,
                format!("{} has no gyro: name a chip that has one", one.describe()),
            )),
            [] if streams.iter().all(|s| s.chip.is_none()) => Err(self.error(
                key,
                format!(
                    "source '{source}' is of Falcon-GX frames, which have no chips: leave \
                     gyro_chip out (the frame's own gyro is used)"
                ),
            )),
            [] => Err(self.error(
                key,
                format!("'{text}' is not on source '{source}': its chips are {listed}"),
            )),
            _ => Err(self.error(
                key,
                format!("'{text}' is ambiguous on source '{source}' ({listed}): give NAME@ADDR"),
            )),
        }
    }

    pub(super) fn check_name(&self, key: &str, name: &str) -> Result<(), ConfigError> {
        let problem = if name.is_empty() {
            Some("empty".to_string())
        } else if name.len() > NAME_MAX {
            Some(format!(
                "{} characters long, at most {NAME_MAX}",
                name.len()
            ))
        } else {
            name.chars()
                .find(|c| !(c.is_ascii_alphanumeric() || *c == '-' || *c == '_'))
                .map(|c| format!("it contains {c:?}"))
        };
        match problem {
            None => Ok(()),
            Some(p) => Err(self.error(
                key,
                format!(
                    "'{name}' is not a usable name ({p}): use letters, digits, '-' and '_' \
                     (it names files and appears in messages)"
                ),
            )),
        }
    }

    /// Seconds from `min` to `max`, both included.
    pub(crate) fn seconds_in(
        &self,
        key: &str,
        value: f64,
        min: f64,
        max: f64,
    ) -> Result<Duration, ConfigError> {
        if value >= min
            && value <= max
            && let Ok(d) = Duration::try_from_secs_f64(value)
        {
            return Ok(d);
        }
        Err(self.error(
            key,
            format!("{value} seconds: give a number of seconds from {min} to {max}"),
        ))
    }

    pub(crate) fn seconds(&self, key: &str, value: f64, max: f64) -> Result<Duration, ConfigError> {
        if value > 0.0
            && value <= max
            && let Ok(d) = Duration::try_from_secs_f64(value)
        {
            return Ok(d);
        }
        Err(self.error(
            key,
            format!("{value} seconds: give a number of seconds above 0 and at most {max}"),
        ))
    }
}

/// Counts per degree/second of a stream's gyro, where the chip (or frame)
/// defines it: the MPU-6050 as the bridge sets it up (+-250 deg/s), the
/// Falcon-GX-style frame as this project defines it.
pub(super) fn gyro_lsb_per_deg_s(stream: StreamDesc) -> Option<f64> {
    match stream.chip {
        None => Some(falcon::RATE_LSB_PER_DEG_S),
        Some((chip, _)) => chip.gyro_lsb_per_deg_s(),
    }
}

/// What a 2-axis sensor's own checks found, for [`Checker::plane_sensor`].
pub(super) struct PlaneSensor {
    pub(super) stream: u8,
    pub(super) field: Field,
    pub(super) axes: [Axis; 2],
    pub(super) effects: Vec<String>,
    pub(super) gyro: GyroChoice,
    pub(super) columns: Option<[String; 2]>,
    pub(super) north: Option<North>,
    pub(super) out_of_plane: Option<OutOfPlane>,
}
