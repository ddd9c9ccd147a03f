//! PNG files that lie: a header claiming any size over one empty data chunk, the bytes a
//! decoder sizes its buffer from before it reads any pixel.

/// A PNG whose header says `width × height` pixels of `depth`-bit `colour` (the PNG colour
/// type: 0 grey, 6 RGBA) and whose data is one empty deflate block.
pub fn png_header(width: u32, height: u32, depth: u8, colour: u8) -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend(height.to_be_bytes());
    ihdr.extend([depth, colour, 0, 0, 0]); // deflate, adaptive filter, no interlace
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
    chunk(&mut png, b"IEND", &[]);
    png
}

/// An 8-bit grey PNG claiming `width × height` pixels ([`png_header`]).
pub fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    png_header(width, height, 8, 0)
}

/// Appends one chunk: length, kind, data, CRC-32 of kind and data.
fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend((data.len() as u32).to_be_bytes());
    let mut body = kind.to_vec();
    body.extend(data);
    out.extend(&body);
    out.extend(roomcal::store::crc32(&body).to_be_bytes());
}
