//! `isochron_msgs/msg/Activity` and `BlockActivity` (ros/isochron_msgs/msg), as
//! serde structs in the `.msg` field order, so that RustDDS writes the CDR every
//! ROS 2 middleware reads (`ros2 topic echo` with the package built), and the
//! conversion from and to the iceoryx2 wire types, which loses nothing.

use serde::{Deserialize, Serialize};

use isochron_shared::wire::{
    ActivityHeader, BlockActivity as WireBlock, CameraId, Preamble, Stream, WireError,
};

/// `isochron_msgs/msg/BlockActivity`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct BlockActivity {
    /// Short-term in-place activity.
    pub s1: f32,
    /// Short-term moving activity.
    pub s2: f32,
    /// In-place flow, x.
    pub s1_dx: f32,
    /// In-place flow, y.
    pub s1_dy: f32,
    /// Moving flow, x.
    pub s2_dx: f32,
    /// Moving flow, y.
    pub s2_dy: f32,
    /// Long-term mean at t*.
    pub lt_mean: f32,
    /// Long-term standard deviation at t*.
    pub lt_sigma: f32,
}

/// `isochron_msgs/msg/Activity`: an `activity` sample's header and blocks.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Activity {
    /// The base station that sent it.
    pub box_id: String,
    /// The camera.
    pub camera: String,
    /// The camera's activity sequence number.
    pub sequence: u64,
    /// Capture time (end of the second), UTC ns.
    pub capture_time_ns: i64,
    /// When capture published the originating frame, UTC ns.
    pub origin_wall_ns: i64,
    /// `FLAG_*` bits.
    pub flags: u32,
    /// Blocks per row.
    pub grid_w: u32,
    /// Block rows.
    pub grid_h: u32,
    /// Block edge, pixels.
    pub block_px: u32,
    /// Frame width, pixels.
    pub frame_width: u32,
    /// Frame height, pixels.
    pub frame_height: u32,
    /// Isochronal minute.
    pub t_star: u32,
    /// Days of long-term data at t*.
    pub model_days: u32,
    /// Frames in this second.
    pub frames: u32,
    /// Source index of the first frame.
    pub first_source_index: u64,
    /// Source index of the last frame.
    pub last_source_index: u64,
    /// Measured frame rate.
    pub frame_rate: f32,
    /// The blocks, row-major.
    pub blocks: Vec<BlockActivity>,
}

impl Activity {
    /// The message of a (valid) activity sample sent by box `box_id`.
    pub fn from_sample(box_id: &str, h: &ActivityHeader, blocks: &[WireBlock]) -> Activity {
        let p = &h.preamble;
        Activity {
            box_id: box_id.to_string(),
            camera: p.camera.as_str().into_owned(),
            sequence: p.sequence,
            capture_time_ns: p.capture_time_ns,
            origin_wall_ns: p.origin_wall_ns,
            flags: p.flags,
            grid_w: h.grid_w,
            grid_h: h.grid_h,
            block_px: h.block_px,
            frame_width: h.frame_width,
            frame_height: h.frame_height,
            t_star: h.t_star,
            model_days: h.model_days,
            frames: h.frames,
            first_source_index: h.first_source_index,
            last_source_index: h.last_source_index,
            frame_rate: h.frame_rate,
            blocks: blocks
                .iter()
                .map(|b| BlockActivity {
                    s1: b.s1,
                    s2: b.s2,
                    s1_dx: b.s1_dx,
                    s1_dy: b.s1_dy,
                    s2_dx: b.s2_dx,
                    s2_dy: b.s2_dy,
                    lt_mean: b.lt_mean,
                    lt_sigma: b.lt_sigma,
                })
                .collect(),
        }
    }

    /// The iceoryx2 sample of this message for `camera`: the header as the
    /// exporting box's cascade wrote it, validated like any received sample (a
    /// message of another camera, or whose sizes disagree, is an error).
    pub fn to_sample(
        &self,
        camera: &CameraId,
    ) -> Result<(ActivityHeader, Vec<WireBlock>), WireError> {
        let mut preamble = Preamble::new::<WireBlock>(
            Stream::Activity,
            CameraId::new(&self.camera).unwrap_or_default(),
            self.sequence,
            self.blocks.len(),
        );
        preamble.capture_time_ns = self.capture_time_ns;
        preamble.origin_wall_ns = self.origin_wall_ns;
        preamble.flags = self.flags;
        let header = ActivityHeader {
            preamble,
            grid_w: self.grid_w,
            grid_h: self.grid_h,
            block_px: self.block_px,
            frame_width: self.frame_width,
            frame_height: self.frame_height,
            t_star: self.t_star,
            model_days: self.model_days,
            frames: self.frames,
            first_source_index: self.first_source_index,
            last_source_index: self.last_source_index,
            frame_rate: self.frame_rate,
            reserved: 0,
        };
        header.validate(camera, self.blocks.len())?;
        let blocks = self
            .blocks
            .iter()
            .map(|b| WireBlock {
                s1: b.s1,
                s2: b.s2,
                s1_dx: b.s1_dx,
                s1_dy: b.s1_dy,
                s2_dx: b.s2_dx,
                s2_dy: b.s2_dy,
                lt_mean: b.lt_mean,
                lt_sigma: b.lt_sigma,
            })
            .collect();
        Ok((header, blocks))
    }

    /// Bytes of the message's serialised payload (little-endian CDR, without the
    /// 4-byte encapsulation header and RTPS framing).
    pub fn cdr_len(&self) -> usize {
        cdr_encoding::to_vec::<_, byteorder::LittleEndian>(self).map_or(0, |v| v.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> (ActivityHeader, Vec<WireBlock>) {
        let cam = CameraId::new("cam01").unwrap();
        let mut p = Preamble::new::<WireBlock>(Stream::Activity, cam, 41, 6);
        p.capture_time_ns = 1_700_000_000_123_456_789;
        p.origin_wall_ns = 1_700_000_000_200_000_000;
        let h = ActivityHeader {
            preamble: p,
            grid_w: 3,
            grid_h: 2,
            block_px: 16,
            frame_width: 48,
            frame_height: 32,
            t_star: 660,
            model_days: 3,
            frames: 10,
            first_source_index: 100,
            last_source_index: 109,
            frame_rate: 10.0,
            reserved: 0,
        };
        let blocks = (0..6)
            .map(|k| WireBlock {
                s1: k as f32,
                s2: 0.5,
                lt_sigma: 0.25,
                ..Default::default()
            })
            .collect();
        (h, blocks)
    }

    #[test]
    fn a_sample_crosses_unchanged() {
        let (h, blocks) = sample();
        let msg = Activity::from_sample("box_a", &h, &blocks);
        let bytes = cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&msg).unwrap();
        let (back, _): (Activity, usize) =
            cdr_encoding::from_bytes::<Activity, byteorder::LittleEndian>(&bytes).unwrap();
        assert_eq!(back, msg);
        let (h2, b2) = back.to_sample(&CameraId::new("cam01").unwrap()).unwrap();
        assert_eq!(b2, blocks);
        assert_eq!(h2.preamble.sequence, 41);
        assert_eq!(h2.preamble.capture_time_ns, h.preamble.capture_time_ns);
        assert_eq!(h2.preamble.origin_wall_ns, h.preamble.origin_wall_ns);
        assert_eq!((h2.t_star, h2.last_source_index), (660, 109));
        assert_eq!(msg.cdr_len(), bytes.len());
    }

    #[test]
    fn a_message_of_another_camera_or_size_is_refused() {
        let (h, blocks) = sample();
        let msg = Activity::from_sample("box_a", &h, &blocks);
        assert!(msg.to_sample(&CameraId::new("cam02").unwrap()).is_err());
        let mut short = msg.clone();
        short.blocks.pop();
        assert!(short.to_sample(&CameraId::new("cam01").unwrap()).is_err());
    }
}
