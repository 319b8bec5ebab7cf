//! The synthetic scenes' semantic classes, like the paper's road classes plus the
//! ignore classes the optimiser must leave out.

use crate::bundle::{ClassRole, SemanticClass};

pub const ROAD: u8 = 0;
pub const LANE_MARKING: u8 = 1;
pub const CROSSWALK: u8 = 2;
pub const CURB: u8 = 3;
pub const SIDEWALK: u8 = 4;
pub const MANHOLE: u8 = 5;
pub const TERRAIN: u8 = 6;
pub const VEHICLE: u8 = 20;
pub const SKY: u8 = 21;

pub fn table() -> Vec<SemanticClass> {
    let c = |id, name: &str, color, role| SemanticClass {
        id,
        name: name.into(),
        color,
        role,
    };
    vec![
        c(ROAD, "road", [128, 64, 128], ClassRole::Road),
        c(
            LANE_MARKING,
            "lane_marking",
            [255, 255, 255],
            ClassRole::Road,
        ),
        c(CROSSWALK, "crosswalk", [255, 200, 0], ClassRole::Road),
        c(CURB, "curb", [196, 196, 196], ClassRole::Road),
        c(SIDEWALK, "sidewalk", [244, 35, 232], ClassRole::Road),
        c(MANHOLE, "manhole", [0, 120, 255], ClassRole::Road),
        c(TERRAIN, "terrain", [152, 251, 152], ClassRole::Road),
        c(VEHICLE, "vehicle", [0, 0, 142], ClassRole::Ignore),
        c(SKY, "sky", [70, 130, 180], ClassRole::Ignore),
    ]
}
