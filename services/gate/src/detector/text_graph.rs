//! The text graph OpenCV's dnn needs beside a TensorFlow Object Detection API SSD
//! (`frozen_inference_graph.pb`), made from the frozen graph itself.
//!
//! OpenCV imports the convolutional body of such a graph but not its TensorFlow
//! pre- and post-processing (the `while` loops of `Preprocessor/map`, the anchor
//! generator, the non-maximum suppression). It takes a second file, a text graph,
//! that keeps the body and replaces the rest by its own layers: `PriorBox` (the
//! anchors, computed from the anchor generator's settings), `DetectionOutput` (box
//! decoding and NMS). This module makes that text graph the way OpenCV's
//! `samples/dnn/tf_text_graph_ssd.py` describes (its method, written anew here for
//! the one case isochron uses: an `ssd_anchor_generator` with a convolutional box
//! predictor, such as SSDLite-MobileNetV2):
//!
//! 1. `cv::dnn::writeTextGraph` writes the frozen graph as text, without weights
//!    (to a file in `/dev/shm`, read back and removed at once);
//! 2. `Identity` nodes are bypassed; constants, the ops OpenCV does not need and
//!    the nodes under `Preprocessor/map`, `MultipleGridAnchorGenerator`,
//!    `Postprocessor` and `Concatenate` are dropped (references to dropped
//!    constants stay: OpenCV reads their weights from the binary graph);
//! 3. the input placeholder feeds the first kept node (the preprocessor's scale);
//! 4. each box predictor's class and box outputs are flattened and concatenated,
//!    a `PriorBox` per predictor layer makes its anchors, and a `DetectionOutput`
//!    decodes and suppresses (output `1×1×N×7`: image, class, score, x1, y1, x2,
//!    y2, normalised to the input);
//! 5. whatever no longer leads to the output is removed.
//!
//! The number of classes is read from the graph (the first class predictor's
//! output channels over its anchors); the anchor settings are those of the Object
//! Detection API's SSD configurations (6 layers, scales 0.2–0.95, aspect ratios 1,
//! 2, ½, 3, ⅓, fewer boxes in the lowest layer), checked against the graph: each
//! box predictor must give 4 values per anchor of its layer.

use std::collections::{HashMap, HashSet};
use std::path::Path;

mod pbtxt;

use pbtxt::{Node, Value, parse_graph, write_graph};

/// Why no text graph could be made.
#[derive(Debug, thiserror::Error)]
pub enum TextGraphError {
    /// OpenCV could not read the frozen graph.
    #[error("OpenCV cannot read it as a TensorFlow graph")]
    OpenCv(#[from] opencv::Error),
    /// The temporary text file could not be written or read.
    #[error("writing its text graph to {path}")]
    Io {
        /// The temporary file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// The frozen graph could not be read.
    #[error("reading it")]
    Read(#[source] std::io::Error),
    /// The graph is not the kind of SSD this module knows.
    #[error("not a TensorFlow Object Detection API SSD graph this detector can load: {0}")]
    Shape(String),
}

/// The SSD settings of the Object Detection API's `ssd_anchor_generator` that the
/// published SSD configurations share.
struct Anchors {
    layers: usize,
    min_scale: f64,
    max_scale: f64,
    aspect_ratios: [f64; 5],
    input_px: f64,
}

const ANCHORS: Anchors = Anchors {
    layers: 6,
    min_scale: 0.2,
    max_scale: 0.95,
    aspect_ratios: [1.0, 2.0, 0.5, 3.0, 0.3333],
    input_px: 300.0,
};

impl Anchors {
    /// Anchor widths and heights of `layer`, input pixels (the lowest layer has
    /// three small boxes, the others one per aspect ratio and one between scales).
    fn sizes(&self, layer: usize) -> (Vec<f64>, Vec<f64>) {
        let scale = |i: usize| {
            if i >= self.layers {
                1.0
            } else {
                self.min_scale
                    + (self.max_scale - self.min_scale) * i as f64 / (self.layers - 1) as f64
            }
        };
        let (mut w, mut h) = (Vec::new(), Vec::new());
        if layer == 0 {
            let s = self.min_scale;
            w.extend([0.1, s * 2f64.sqrt(), s * 0.5f64.sqrt()]);
            h.extend([0.1, s / 2f64.sqrt(), s / 0.5f64.sqrt()]);
        } else {
            let s = scale(layer);
            for ar in self.aspect_ratios {
                w.push(s * ar.sqrt());
                h.push(s / ar.sqrt());
            }
            let between = (s * scale(layer + 1)).sqrt();
            w.push(between);
            h.push(between);
        }
        let px = |v: Vec<f64>| v.into_iter().map(|x| x * self.input_px).collect();
        (px(w), px(h))
    }
}

/// The ops the SSD body is made of, which OpenCV imports.
const KEEP_OPS: [&str; 19] = [
    "Conv2D",
    "BiasAdd",
    "Add",
    "AddV2",
    "Relu",
    "Relu6",
    "Placeholder",
    "FusedBatchNorm",
    "DepthwiseConv2dNative",
    "ConcatV2",
    "Mul",
    "MaxPool",
    "AvgPool",
    "Identity",
    "Sub",
    "ResizeNearestNeighbor",
    "Pad",
    "FusedBatchNormV3",
    "Mean",
];

/// Scopes of TensorFlow's own pre- and post-processing, replaced by OpenCV layers.
const DROP_SCOPES: [&str; 4] = [
    "MultipleGridAnchorGenerator/",
    "Concatenate/",
    "Postprocessor/",
    "Preprocessor/map",
];

/// Attributes OpenCV's importer does not read.
const UNUSED_ATTRS: [&str; 10] = [
    "T",
    "Tshape",
    "N",
    "Tidx",
    "Tdim",
    "use_cudnn_on_gpu",
    "Index",
    "Tperm",
    "is_training",
    "Tpaddings",
];

/// The name of the output layer of the text graph.
pub const OUTPUT: &str = "detection_out";

/// The text graph of the SSD frozen graph `pb`, and the number of object classes
/// it detects (without the background).
pub fn ssd_text_graph(pb: &Path) -> Result<(String, usize), TextGraphError> {
    // In /dev/shm where there is one: under the systemd units the rest of the
    // filesystem, /tmp included, is read-only for the gate.
    let shm = Path::new("/dev/shm");
    let dir = if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    let dump = dir.join(format!(
        "isochron-ssd-{}-{:?}.pbtxt",
        std::process::id(),
        std::thread::current().id()
    ));
    let dump_name = dump.to_string_lossy().into_owned();
    let io = |source| TextGraphError::Io {
        path: dump_name.clone(),
        source,
    };
    let pb_name = pb.to_string_lossy();
    let written = opencv::dnn::write_text_graph(&pb_name, &dump_name);
    let text = written
        .map_err(TextGraphError::from)
        .and_then(|()| std::fs::read_to_string(&dump).map_err(io));
    let _ = std::fs::remove_file(&dump);
    let nodes = parse_graph(&text?)?;
    let (nodes, classes) = transform(nodes)?;
    Ok((write_graph(&nodes), classes))
}

/// A node of `op` named `name` with `inputs` and no attributes.
fn node(name: &str, op: &str, inputs: &[&str]) -> Node {
    Node {
        name: name.into(),
        op: op.into(),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        attr: Vec::new(),
    }
}

/// An attribute value holding a scalar (`b`, `i`, `f`, `s`).
fn scalar(kind: &str, v: impl ToString) -> Value {
    Value::Message(vec![(kind.into(), Value::Scalar(v.to_string()))])
}

/// An attribute value holding a one-dimensional tensor.
fn tensor<T: ToString>(values: &[T], float: bool) -> Value {
    let (dtype, field) = if float {
        ("DT_FLOAT", "float_val")
    } else {
        ("DT_INT32", "int_val")
    };
    let mut t = vec![
        ("dtype".into(), Value::Scalar(dtype.into())),
        (
            "tensor_shape".into(),
            Value::Message(vec![(
                "dim".into(),
                Value::Message(vec![(
                    "size".into(),
                    Value::Scalar(values.len().to_string()),
                )]),
            )]),
        ),
    ];
    for v in values {
        t.push((field.into(), Value::Scalar(v.to_string())));
    }
    Value::Message(vec![("tensor".into(), Value::Message(t))])
}

/// A constant node of int32 `values`.
fn const_node(name: &str, values: &[i32]) -> Node {
    let mut n = node(name, "Const", &[]);
    n.attr.push(("value".into(), tensor(values, false)));
    n
}

/// The output channels of a convolution's weights constant, if the text graph
/// kept its shape (`[h, w, in, out]`).
fn out_channels(consts: &HashMap<String, Node>, weights: &str) -> Option<usize> {
    let c = consts.get(weights)?;
    let (_, Value::Message(value)) = c.attr.iter().find(|(k, _)| k == "value")? else {
        return None;
    };
    let Value::Message(t) = &value.iter().find(|(k, _)| k == "tensor")?.1 else {
        return None;
    };
    let Value::Message(shape) = &t.iter().find(|(k, _)| k == "tensor_shape")?.1 else {
        return None;
    };
    let dims: Vec<usize> = shape
        .iter()
        .filter(|(k, _)| k == "dim")
        .filter_map(|(_, d)| match d {
            Value::Message(d) => d.iter().find_map(|(k, v)| match (k.as_str(), v) {
                ("size", Value::Scalar(s)) => s.parse().ok(),
                _ => None,
            }),
            Value::Scalar(_) => None,
        })
        .collect();
    (dims.len() == 4).then(|| dims[3])
}

/// Steps 2–5 of the module doc on the nodes of the frozen graph: the text graph's
/// nodes and the number of classes.
fn transform(mut nodes: Vec<Node>) -> Result<(Vec<Node>, usize), TextGraphError> {
    let classes = classes(&nodes)?;
    prune(&mut nodes);
    let input = connect_input(&mut nodes)?;
    add_head(&mut nodes, classes, &input)?;
    remove_dead(&mut nodes);
    Ok((nodes, classes))
}

/// The number of classes, read from the class predictors; each box predictor
/// checked to give 4 values per anchor of its layer.
fn classes(nodes: &[Node]) -> Result<usize, TextGraphError> {
    let shape = |s: String| TextGraphError::Shape(s);
    let consts: HashMap<String, Node> = nodes
        .iter()
        .filter(|n| n.op == "Const")
        .map(|n| (n.name.clone(), n.clone()))
        .collect();
    // The predictors' weights, for the number of classes and the anchor check.
    let weights_of = |nodes: &[Node], conv: &str| -> Option<usize> {
        let n = nodes.iter().find(|n| n.name == conv)?;
        let w = n.input.get(1)?;
        let w = nodes
            .iter()
            .find(|m| &m.name == w && m.op == "Identity")
            .and_then(|m| m.input.first())
            .unwrap_or(w);
        out_channels(&consts, w)
    };
    let anchors_per_layer: Vec<usize> = (0..ANCHORS.layers)
        .map(|i| ANCHORS.sizes(i).0.len())
        .collect();
    let mut classes = None;
    for (i, anchors) in anchors_per_layer.iter().enumerate() {
        let boxes = weights_of(
            nodes,
            &format!("BoxPredictor_{i}/BoxEncodingPredictor/Conv2D"),
        )
        .ok_or_else(|| shape(format!("no BoxPredictor_{i}/BoxEncodingPredictor/Conv2D")))?;
        if boxes != anchors * 4 {
            return Err(shape(format!(
                "box predictor {i} gives {boxes} values per place, expected {} ({anchors} anchors)",
                anchors * 4
            )));
        }
        let scores = weights_of(nodes, &format!("BoxPredictor_{i}/ClassPredictor/Conv2D"))
            .ok_or_else(|| shape(format!("no BoxPredictor_{i}/ClassPredictor/Conv2D")))?;
        if scores % anchors != 0 || scores / anchors < 2 {
            return Err(shape(format!(
                "class predictor {i} gives {scores} scores per place for {anchors} anchors"
            )));
        }
        let c = scores / anchors - 1;
        if classes.is_some_and(|k| k != c) {
            return Err(shape("the class predictors disagree on the classes".into()));
        }
        classes = Some(c);
    }
    Ok(classes.unwrap_or(1))
}

/// Bypasses `Identity` nodes; drops constants, the ops OpenCV does not need and
/// TensorFlow's pre- and post-processing.
fn prune(nodes: &mut Vec<Node>) {
    // Bypass Identity nodes.
    let mut identity: HashMap<String, String> = HashMap::new();
    for n in nodes.iter() {
        if (n.op == "Identity" || n.op == "IdentityN")
            && let Some(first) = n.input.first()
        {
            let to = identity
                .get(first)
                .cloned()
                .unwrap_or_else(|| first.clone());
            identity.insert(n.name.clone(), to);
        }
    }
    nodes.retain(|n| !identity.contains_key(&n.name));
    for n in nodes.iter_mut() {
        for i in &mut n.input {
            if let Some(to) = identity.get(i) {
                *i = to.clone();
            }
        }
    }

    // Drop constants, unneeded ops and TensorFlow's pre-/post-processing.
    let mut removed = HashSet::new();
    nodes.retain(|n| {
        let drop = n.op == "Const"
            || !KEEP_OPS.contains(&n.op.as_str())
            || DROP_SCOPES.iter().any(|s| n.name.starts_with(s));
        if drop && n.op != "Const" {
            removed.insert(n.name.clone());
        }
        !drop
    });
    for n in nodes.iter_mut() {
        n.input.retain(|i| !removed.contains(i));
        n.attr.retain(|(k, _)| !UNUSED_ATTRS.contains(&k.as_str()));
    }
}

/// Feeds the input placeholder to the first kept node; the input's name.
fn connect_input(nodes: &mut [Node]) -> Result<String, TextGraphError> {
    let shape = |s: String| TextGraphError::Shape(s);
    // The input feeds the first kept node.
    if nodes.len() < 4 || nodes[0].op != "Placeholder" {
        return Err(shape(
            "the graph does not start with its input placeholder".into(),
        ));
    }
    let input = nodes[0].name.clone();
    let weights = nodes[1]
        .input
        .last()
        .cloned()
        .ok_or_else(|| shape(format!("{} has no inputs", nodes[1].name)))?;
    nodes[1].input = vec![input.clone(), weights];
    let pre = "Preprocessor/";
    if nodes[2].name.starts_with(pre)
        && nodes[2].input.first().is_some_and(|i| i.starts_with(pre))
        && !nodes[3].input.iter().any(|i| i.contains(pre))
    {
        let name = nodes[2].name.clone();
        nodes[3].input.insert(0, name);
    }
    Ok(input)
}

/// The SSD head: flattened predictions, anchors, decoding.
fn add_head(nodes: &mut Vec<Node>, classes: usize, input: &str) -> Result<(), TextGraphError> {
    let shape = |s: String| TextGraphError::Shape(s);
    nodes.push(const_node("concat/axis_flatten", &[-1]));
    for label in ["ClassPredictor", "BoxEncodingPredictor"] {
        let mut flat = Vec::new();
        for i in 0..ANCHORS.layers {
            let from = format!("BoxPredictor_{i}/{label}/BiasAdd");
            let name = format!("{from}/Flatten");
            nodes.push(node(&name, "Flatten", &[&from]));
            flat.push(name);
        }
        flat.push("concat/axis_flatten".into());
        let refs: Vec<&str> = flat.iter().map(String::as_str).collect();
        nodes.push(node(&format!("{label}/concat"), "ConcatV2", &refs));
    }
    let mut transposed = 0;
    for n in nodes.iter_mut() {
        let is_box_conv = (0..ANCHORS.layers).any(|i| {
            n.name == format!("BoxPredictor_{i}/BoxEncodingPredictor/Conv2D")
                || n.name == format!("BoxPredictor_{i}/BoxEncodingPredictor/convolution")
        });
        if is_box_conv {
            n.attr
                .push(("loc_pred_transposed".into(), scalar("b", "true")));
            transposed += 1;
        }
    }
    if transposed != ANCHORS.layers {
        return Err(shape(format!(
            "{transposed} box encoding convolutions, expected {}",
            ANCHORS.layers
        )));
    }
    let mut priors = Vec::new();
    for i in 0..ANCHORS.layers {
        let name = format!("PriorBox_{i}");
        let from = format!("BoxPredictor_{i}/BoxEncodingPredictor/BiasAdd");
        let mut p = node(&name, "PriorBox", &[&from, input]);
        let (w, h) = ANCHORS.sizes(i);
        p.attr.push(("clip".into(), scalar("b", "false")));
        p.attr.push(("flip".into(), scalar("b", "false")));
        p.attr.push(("height".into(), tensor(&h, true)));
        // The box coder's scales 10, 10, 5, 5, inverted.
        p.attr
            .push(("variance".into(), tensor(&[0.1, 0.1, 0.2, 0.2], true)));
        p.attr.push(("width".into(), tensor(&w, true)));
        nodes.push(p);
        priors.push(name);
    }
    priors.push("concat/axis_flatten".into());
    let refs: Vec<&str> = priors.iter().map(String::as_str).collect();
    nodes.push(node("PriorBox/concat", "ConcatV2", &refs));
    let shape3d = [0, -1, classes as i32 + 1];
    nodes.push(const_node("ClassPredictor/concat3d/shape", &shape3d));
    nodes.push(node(
        "ClassPredictor/concat3d",
        "Reshape",
        &["ClassPredictor/concat", "ClassPredictor/concat3d/shape"],
    ));
    nodes.push(node(
        "ClassPredictor/concat/sigmoid",
        "Sigmoid",
        &["ClassPredictor/concat3d"],
    ));
    nodes.push(node(
        "ClassPredictor/concat/sigmoid/Flatten",
        "Flatten",
        &["ClassPredictor/concat/sigmoid"],
    ));
    let mut out = node(
        OUTPUT,
        "DetectionOutput",
        &[
            "BoxEncodingPredictor/concat",
            "ClassPredictor/concat/sigmoid/Flatten",
            "PriorBox/concat",
        ],
    );
    out.attr
        .push(("background_label_id".into(), scalar("i", 0)));
    out.attr
        .push(("code_type".into(), scalar("s", "\"CENTER_SIZE\"")));
    out.attr
        .push(("confidence_threshold".into(), scalar("f", 0.01)));
    out.attr.push(("keep_top_k".into(), scalar("i", 100)));
    out.attr.push(("nms_threshold".into(), scalar("f", 0.6)));
    out.attr
        .push(("num_classes".into(), scalar("i", classes + 1)));
    out.attr
        .push(("share_location".into(), scalar("b", "true")));
    out.attr.push(("top_k".into(), scalar("i", 100)));
    nodes.push(out);
    Ok(())
}

/// Removes what no longer leads anywhere (the output aside), until stable.
fn remove_dead(nodes: &mut Vec<Node>) {
    loop {
        let used: HashSet<&str> = nodes
            .iter()
            .flat_map(|n| n.input.iter().map(String::as_str))
            .collect();
        let dead: HashSet<String> = nodes
            .iter()
            .filter(|n| n.name != OUTPUT && !used.contains(n.name.as_str()))
            .map(|n| n.name.clone())
            .collect();
        if dead.is_empty() {
            break;
        }
        nodes.retain(|n| !dead.contains(&n.name));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_are_those_of_the_ssd_configurations() {
        let (w0, h0) = ANCHORS.sizes(0);
        assert_eq!(w0.len(), 3);
        assert!((w0[0] - 30.0).abs() < 1e-9 && (h0[0] - 30.0).abs() < 1e-9);
        let (w5, h5) = ANCHORS.sizes(5);
        assert_eq!(w5.len(), 6);
        // Scale 0.95 at aspect 1, then between 0.95 and 1.
        assert!((w5[0] - 285.0).abs() < 1e-9 && (h5[0] - 285.0).abs() < 1e-9);
        assert!((w5[5] - 0.95f64.sqrt() * 300.0).abs() < 1e-9);
    }
}
