//! The class map: how a segmentation model's input is made and how its outputs become
//! a bundle's classes (a JSON file, or the built-in `twinlitenet`).

use crate::bundle::{ClassRole, SemanticClass};
use serde::{Deserialize, Serialize};

/// The model's input: its size and the normalisation of RGB in 0..1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    pub width: u32,
    pub height: u32,
    /// RGB in 0..1 is multiplied by this (255 for models fed 0..255).
    #[serde(default = "one")]
    pub scale: f32,
    #[serde(default)]
    pub mean: [f32; 3],
    #[serde(default = "ones")]
    pub std: [f32; 3],
}

fn one() -> f32 {
    1.0
}

fn ones() -> [f32; 3] {
    [1.0; 3]
}

/// A pixel is of `class` when the argmax of output `output` is `channel` (rules are
/// tried in order, the first that holds wins).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rule {
    pub output: String,
    pub channel: usize,
    pub class: u8,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassMap {
    pub input: InputSpec,
    /// The bundle's class table the labels use.
    pub classes: Vec<SemanticClass>,
    pub outputs: Vec<Rule>,
    /// The class of a pixel no rule claims.
    pub default: u8,
}

/// TwinLiteNet's classes: the KITTI importer's `--classes twinlitenet` too.
pub fn twinlitenet_classes() -> Vec<SemanticClass> {
    let class = SemanticClass::new;
    vec![
        class(0, "other", [0, 0, 0], ClassRole::Ignore),
        class(1, "road", [128, 64, 128], ClassRole::Road),
        class(2, "lane_marking", [255, 255, 255], ClassRole::Road),
    ]
}

impl ClassMap {
    /// TwinLiteNet's (shared/models/twinlitenet): 320×320 RGB in 0..1; a lane line
    /// where `lanes` says 1, else road where `drivable_area` says 1, else other. The
    /// classes are the KITTI importer's `--classes twinlitenet`.
    pub fn twinlitenet() -> Self {
        Self {
            input: InputSpec {
                width: 320,
                height: 320,
                scale: 1.0,
                mean: [0.0; 3],
                std: [1.0; 3],
            },
            classes: twinlitenet_classes(),
            outputs: vec![
                Rule {
                    output: "lanes".into(),
                    channel: 1,
                    class: 2,
                },
                Rule {
                    output: "drivable_area".into(),
                    channel: 1,
                    class: 1,
                },
            ],
            default: 0,
        }
    }

    /// Reads a class map from JSON (`name` in errors), checking that every class it
    /// makes is in its table and that the table has a road class.
    pub fn from_json(name: &str, text: &[u8]) -> Result<Self, String> {
        let de = &mut serde_json::Deserializer::from_slice(text);
        let map: Self = serde_path_to_error::deserialize(de).map_err(|e| {
            format!(
                "{name}: {} at {}; expected {{\"input\": {{\"width\", \"height\", \"scale\", \
                 \"mean\", \"std\"}}, \"classes\": [bundle classes], \"outputs\": \
                 [{{\"output\", \"channel\", \"class\"}}], \"default\": id}} (docs/SEGMENT.md)",
                e.inner(),
                e.path()
            )
        })?;
        let known = |id: u8| map.classes.iter().any(|c| c.id == id);
        for (i, r) in map.outputs.iter().enumerate() {
            if !known(r.class) {
                return Err(format!(
                    "{name}: outputs[{i}].class {} is not a class of \"classes\"",
                    r.class
                ));
            }
        }
        if !known(map.default) {
            return Err(format!(
                "{name}: default {} is not a class of \"classes\"",
                map.default
            ));
        }
        if !map.classes.iter().any(|c| c.role == ClassRole::Road) {
            return Err(format!(
                "{name}: no class has role \"road\"; nothing would be reconstructed"
            ));
        }
        let s = &map.input;
        if !(1..=4096).contains(&s.width) || !(1..=4096).contains(&s.height) {
            return Err(format!(
                "{name}: input {}×{}; expected 1..=4096 pixels per side",
                s.width, s.height
            ));
        }
        if s.std.iter().any(|v| !(v.is_finite() && *v != 0.0)) || !s.scale.is_finite() {
            return Err(format!("{name}: input.std must be finite and non-zero"));
        }
        Ok(map)
    }
}
