//! The PDF writer: the flattened picture ([`opaque::regions`]) as vector paths on one page, so
//! that it needs no additive blend mode (PDF has `Multiply` but none that adds).
//!
//! The page is the original image's size at 96 px per inch (as SVG's `px`), the working canvas
//! scaled onto it. Colours are DeviceRGB with the sRGB values files hold.

use pdf_writer::{Content, Filter, Pdf, Rect, Ref};

use crate::opaque;
use crate::scene::Scene;

/// PDF points per CSS pixel (72 per inch over 96 per inch).
const POINTS_PER_PIXEL: f32 = 0.75;

/// Coordinates are written rounded to 1/100 of a working pixel, which no anti-aliased edge
/// shows, instead of every digit of an f32: the content stream about halves.
const STEPS_PER_PIXEL: f32 = 100.0;

fn rounded(v: f32) -> f32 {
    (v * STEPS_PER_PIXEL).round() / STEPS_PER_PIXEL
}

/// The PDF of `scene` as shown. Equal scenes give byte-identical files.
pub fn to_pdf(scene: &Scene) -> Vec<u8> {
    let (catalog, pages, page, contents) = (Ref::new(1), Ref::new(2), Ref::new(3), Ref::new(4));
    let width = scene.original_width as f32 * POINTS_PER_PIXEL;
    let height = scene.original_height as f32 * POINTS_PER_PIXEL;
    let mut pdf = Pdf::new();
    pdf.catalog(catalog).pages(pages);
    pdf.pages(pages).kids([page]).count(1);
    pdf.page(page)
        .parent(pages)
        .media_box(Rect::new(0.0, 0.0, width, height))
        .contents(contents);

    let mut content = Content::new();
    // Working-canvas coordinates, y down, onto the page (PDF's y points up).
    let sx = width / scene.width.max(1) as f32;
    let sy = height / scene.height.max(1) as f32;
    content.transform([sx, 0.0, 0.0, -sy, 0.0, height]);
    for region in opaque::regions(scene) {
        let [r, g, b] = region.color;
        content.set_fill_rgb(r, g, b);
        let mut any = false;
        for contour in region.contours.iter().filter(|c| c.len() >= 3) {
            content.move_to(rounded(contour[0].x), rounded(contour[0].y));
            for p in &contour[1..] {
                content.line_to(rounded(p.x), rounded(p.y));
            }
            content.close_path();
            any = true;
        }
        if any {
            content.fill_nonzero();
        }
    }
    // Deflated: the polygons' coordinates shrink about 3× (PDF readers all inflate FlateDecode).
    let data = miniz_oxide::deflate::compress_to_vec_zlib(&content.finish(), 6);
    pdf.stream(contents, &data).filter(Filter::FlateDecode);
    pdf.finish()
}
