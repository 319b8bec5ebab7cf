//! GeoTIFF layers for GIS tools (QGIS, GDAL): `elevation.tif` (float32 metres, NaN
//! no-data where the map is empty), `rgb.tif` (RGBA, alpha 0 where empty) and
//! `semantic.tif` (class ids, 255 no-data), each exactly the map's size, with the
//! georeference as GeoTIFF tags: the upper-left corner of pixel (0, 0) tied to the
//! map's origin (west edge, north edge), square pixels of the map's resolution, and a
//! user-defined (local engineering) model, named in the citation, because a bundle's
//! world frame has no CRS.

use crate::bev::BevGeometry;
use std::io::Cursor;
use tiff::encoder::{colortype, compression::DeflateLevel, Compression, TiffEncoder};
use tiff::tags::Tag;

/// GeoTIFF tag numbers (GeoTIFF 1.1, and GDAL's no-data tag).
const MODEL_PIXEL_SCALE: u16 = 33550;
const MODEL_TIEPOINT: u16 = 33922;
const GEO_KEY_DIRECTORY: u16 = 34735;
const GEO_ASCII_PARAMS: u16 = 34737;
const GDAL_NODATA: u16 = 42113;
/// `ExtraSamples` = 2: the fourth sample is unassociated alpha.
const EXTRA_SAMPLES: u16 = 338;

/// Class id written where the map is empty.
pub const SEMANTIC_NODATA: u8 = 255;

/// The georeference tags of a map of geometry `g` in the frame named `frame`.
fn georeference<W: std::io::Write + std::io::Seek, C: colortype::ColorType>(
    img: &mut tiff::encoder::ImageEncoder<'_, W, C, tiff::encoder::TiffKindStandard>,
    g: &BevGeometry,
    frame: &str,
) -> tiff::TiffResult<()> {
    let e = img.encoder();
    e.write_tag(
        Tag::Unknown(MODEL_PIXEL_SCALE),
        &[g.resolution, g.resolution, 0.0][..],
    )?;
    e.write_tag(
        Tag::Unknown(MODEL_TIEPOINT),
        &[0.0, 0.0, 0.0, g.origin[0], g.origin[1], 0.0][..],
    )?;
    let citation = format!("rogs local frame: {frame}|");
    // Version 1.1.0, 3 keys: GTModelType user-defined, GTRasterType PixelIsArea,
    // GTCitation (from the ASCII parameters).
    let keys: [u16; 16] = [
        1,
        1,
        0,
        3,
        1024,
        0,
        1,
        32767,
        1025,
        0,
        1,
        1,
        1026,
        GEO_ASCII_PARAMS,
        citation.len() as u16,
        0,
    ];
    e.write_tag(Tag::Unknown(GEO_KEY_DIRECTORY), &keys[..])?;
    e.write_tag(Tag::Unknown(GEO_ASCII_PARAMS), citation.as_str())?;
    Ok(())
}

/// The one tag that differs between the layers.
enum Extra<'a> {
    /// GDAL's no-data value, as text.
    NoData(&'a str),
    /// `ExtraSamples`: the fourth sample is unassociated alpha.
    Alpha,
}

/// One georeferenced, deflated layer of colour type `C` with its extra tag.
fn tif<C: colortype::ColorType>(
    name: &str,
    data: &[C::Inner],
    g: &BevGeometry,
    frame: &str,
    extra: Extra,
) -> Result<Vec<u8>, String>
where
    [C::Inner]: tiff::encoder::TiffValue,
{
    let write = || -> tiff::TiffResult<Vec<u8>> {
        let mut out = Cursor::new(Vec::new());
        let mut enc = TiffEncoder::new(&mut out)?
            .with_compression(Compression::Deflate(DeflateLevel::Balanced));
        let mut img = enc.new_image::<C>(g.width, g.height)?;
        georeference(&mut img, g, frame)?;
        match extra {
            Extra::NoData(v) => img.encoder().write_tag(Tag::Unknown(GDAL_NODATA), v)?,
            Extra::Alpha => img
                .encoder()
                .write_tag(Tag::Unknown(EXTRA_SAMPLES), &[2u16][..])?,
        }
        img.write_data(data)?;
        Ok(out.into_inner())
    };
    write().map_err(|e| format!("{name}: {e}"))
}

/// Float32 elevation (or any value layer), NaN where empty.
pub fn float_tif(name: &str, v: &[f32], g: &BevGeometry, frame: &str) -> Result<Vec<u8>, String> {
    tif::<colortype::Gray32Float>(name, v, g, frame, Extra::NoData("nan"))
}

/// RGBA colours, alpha 0 where empty.
pub fn rgba_tif(name: &str, px: &[u8], g: &BevGeometry, frame: &str) -> Result<Vec<u8>, String> {
    tif::<colortype::RGBA8>(name, px, g, frame, Extra::Alpha)
}

/// Class ids, `SEMANTIC_NODATA` where empty.
pub fn ids_tif(name: &str, ids: &[u8], g: &BevGeometry, frame: &str) -> Result<Vec<u8>, String> {
    let nodata = SEMANTIC_NODATA.to_string();
    tif::<colortype::Gray8>(name, ids, g, frame, Extra::NoData(&nodata))
}
