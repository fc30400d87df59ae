//! What the benchmarks share: a simulated compass turning on a
//! Falcon-GX-style IMU with 1 % garbage on the line, as chunks or as a
//! capture file. (A folder module, so cargo does not take it for a bench.)
//!
//! Each benchmark uses a part of it.
#![allow(dead_code)]

use std::io::Write;

use fieldcal::capture::{CaptureHeader, CaptureWriter, Chunk};
use fieldcal::sim::{FalconWire, SimSensor};

/// A noisy compass with small offsets and a 5 % gain mismatch, turning
/// `turns` times (200 frames, 50 ms apart, a turn).
pub fn compass(turns: f64) -> SimSensor {
    SimSensor {
        offset_x: 30.0,
        offset_y: -20.0,
        gain_x: 1.05,
        noise: 3.0,
        turns,
        ..Default::default()
    }
}

/// The sensor's frames on the wire with 1 % garbage, chunk by chunk.
pub fn falcon_chunks(sensor: &SimSensor) -> (CaptureHeader, Vec<Chunk>) {
    sensor
        .falcon_capture(&FalconWire {
            garbage: 0.01,
            ..Default::default()
        })
        .expect("simulated capture")
}

/// The sensor's capture written to `out`, which is returned flushed.
pub fn write_capture<W: Write>(out: W, sensor: &SimSensor) -> W {
    let (header, chunks) = falcon_chunks(sensor);
    let mut writer = CaptureWriter::new(out, &header).expect("capture header");
    for chunk in &chunks {
        writer
            .write_chunk(chunk.time, chunk.stream, &chunk.bytes)
            .expect("capture chunk");
    }
    writer.into_inner().expect("capture written")
}
