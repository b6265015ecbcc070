//! What each piece of the 2-D map is: the body part (the calibration's link)
//! its taxels are on, and the regions that hold it whole, as labels the page
//! draws over the map; and each taxel's place (its link and regions) for the
//! page's tooltip.
//!
//! The map flattens each connected surface piece on its own and packs the
//! pieces side by side, so a link cut into many pieces (an iCub layer's 64
//! triangle modules, which touch no other) would get as many labels: pieces
//! of one link are labelled together, under one label for the box around
//! them, as long as that box holds no piece of another link.

#![forbid(unsafe_code)]

use std::collections::HashMap;

use skinware_geometry::SkinGeometry;

/// Above this many pieces, each is labelled on its own (the grouping costs
/// a look at every piece for each pair tried); the page leaves out labels
/// that do not fit their piece.
const MAX_PIECES_GROUPED: usize = 256;

/// One label of the map.
#[derive(Clone, Debug, PartialEq)]
pub struct PieceLabel {
    /// The box of the pieces it names, map metres: min x, min y, max x, max y.
    pub bounds: [f32; 4],
    /// The link's name, then ` · ` and the regions that hold every taxel of
    /// those pieces, if any (other than one named as the link).
    pub text: String,
}

/// The labels of `geometry`'s map pieces: one per link, or more where a
/// link's pieces lie among another link's.
pub fn piece_labels(geometry: &SkinGeometry) -> Vec<PieceLabel> {
    let map = &geometry.map;
    let pieces = map.piece_bounds.len();
    let mut members = vec![Vec::new(); pieces];
    for (sensor, &piece) in map.piece_of.iter().enumerate() {
        if let Some(list) = members.get_mut(piece as usize) {
            list.push(sensor as u32);
        }
    }
    // Each piece's link: the one most of its taxels are on.
    let link_of_piece: Vec<Option<u16>> = members
        .iter()
        .map(|sensors| {
            let mut counts: HashMap<u16, usize> = HashMap::new();
            for &s in sensors {
                if let Some(&link) = geometry.link_of.get(s as usize) {
                    *counts.entry(link).or_default() += 1;
                }
            }
            counts.into_iter().max_by_key(|&(link, count)| (count, std::cmp::Reverse(link))).map(|(link, _)| link)
        })
        .collect();
    let mut groups: Vec<Group> = (0..pieces)
        .filter_map(|p| Some(Group { link: link_of_piece[p]?, bounds: map.piece_bounds[p], pieces: vec![p] }))
        .collect();
    if pieces <= MAX_PIECES_GROUPED {
        merge_groups(&mut groups, &map.piece_bounds, &link_of_piece);
    }
    groups
        .iter()
        .filter_map(|group| {
            let link = geometry.links.get(usize::from(group.link))?;
            let sensors: Vec<u32> = group.pieces.iter().flat_map(|&p| members[p].iter().copied()).collect();
            let text = with_regions(link, &whole_regions(geometry, &sensors));
            (!text.is_empty()).then_some(PieceLabel { bounds: group.bounds, text })
        })
        .collect()
}

/// Pieces of one link under one label.
struct Group {
    link: u16,
    bounds: [f32; 4],
    pieces: Vec<usize>,
}

fn union(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    [a[0].min(b[0]), a[1].min(b[1]), a[2].max(b[2]), a[3].max(b[3])]
}

fn overlap(a: [f32; 4], b: [f32; 4]) -> bool {
    a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3]
}

/// Merges groups of the same link, two at a time, while the box around
/// both holds no piece of another link.
fn merge_groups(groups: &mut Vec<Group>, piece_bounds: &[[f32; 4]], link_of_piece: &[Option<u16>]) {
    let mut merged = true;
    while merged {
        merged = false;
        let mut i = 0;
        while i < groups.len() {
            let mut j = i + 1;
            while j < groups.len() {
                let both = union(groups[i].bounds, groups[j].bounds);
                let clear = groups[i].link == groups[j].link
                    && piece_bounds
                        .iter()
                        .zip(link_of_piece)
                        .all(|(&bounds, &link)| link == Some(groups[i].link) || !overlap(both, bounds));
                if clear {
                    let absorbed = groups.swap_remove(j);
                    groups[i].bounds = both;
                    groups[i].pieces.extend(absorbed.pieces);
                    merged = true;
                } else {
                    j += 1;
                }
            }
            i += 1;
        }
    }
}

/// The regions that hold every one of `sensors` (ascending global indices).
fn whole_regions<'g>(geometry: &'g SkinGeometry, sensors: &[u32]) -> Vec<&'g str> {
    let regions = &geometry.regions;
    regions
        .names
        .iter()
        .zip(&regions.sensors)
        .filter(|(_, held)| !sensors.is_empty() && sensors.iter().all(|s| held.binary_search(s).is_ok()))
        .map(|(name, _)| name.as_str())
        .collect()
}

/// `link · region, region`, leaving out a region named as the link.
fn with_regions(link: &str, regions: &[&str]) -> String {
    let others: Vec<&str> = regions.iter().copied().filter(|&region| region != link).collect();
    if others.is_empty() { link.to_owned() } else { format!("{link} · {}", others.join(", ")) }
}

/// Where each taxel is on the body, as the tooltip says it: the distinct
/// places (a link and the regions holding a taxel), and each taxel's.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Places {
    /// Each place, as text: `link L · regions A, B` (or fewer parts).
    pub texts: Vec<String>,
    /// Each taxel's place, an index into `texts`, in global sensor order.
    pub place_of: Vec<u32>,
}

/// The places of `geometry`'s taxels.
pub fn places(geometry: &SkinGeometry) -> Places {
    let sensors = geometry.sensor_count();
    let regions = &geometry.regions;
    let mut subregion_of: Vec<Option<u32>> = vec![None; sensors];
    for (sub, list) in regions.subregion_sensors.iter().enumerate() {
        for &s in list {
            if let Some(slot) = subregion_of.get_mut(s as usize) {
                *slot = Some(sub as u32);
            }
        }
    }
    let mut index: HashMap<(Option<u16>, Option<u32>), u32> = HashMap::new();
    let mut places = Places { texts: Vec::new(), place_of: Vec::with_capacity(sensors) };
    for (sensor, &subregion) in subregion_of.iter().enumerate() {
        let link = geometry.link_of.get(sensor).copied();
        let place = *index.entry((link, subregion)).or_insert_with(|| {
            let link = link.and_then(|l| geometry.links.get(usize::from(l))).filter(|name| !name.is_empty());
            let names: Vec<&str> = subregion
                .and_then(|sub| regions.regions_of.get(sub as usize))
                .map(|of| of.iter().filter_map(|&r| regions.names.get(r as usize)).map(String::as_str).collect())
                .unwrap_or_default();
            let mut parts = Vec::new();
            if let Some(link) = link {
                parts.push(format!("link {link}"));
            }
            if !names.is_empty() {
                parts.push(format!("{} {}", if names.len() == 1 { "region" } else { "regions" }, names.join(", ")));
            }
            places.texts.push(parts.join(" · "));
            (places.texts.len() - 1) as u32
        });
        places.place_of.push(place);
    }
    places
}

#[cfg(test)]
mod tests {
    use skinware::TopologyBuilder;
    use skinware_geometry::{Calibration, RegionSpec, Selector, SensorCalibration};

    use super::*;

    /// `modules` modules of 12 taxels (4 × 3 on a 4 mm grid), each 20 mm
    /// from the next, so that each is a piece of its own; module `m` is on
    /// link `link(m)`.
    fn modules_apart(modules: u32, link: impl Fn(u32) -> &'static str, regions: &[RegionSpec]) -> SkinGeometry {
        let mut builder = TopologyBuilder::new("layer", "pressure", 50.0);
        builder.patch(1);
        for m in 0..modules {
            builder.module(m + 1, m * 12 + 1..=m * 12 + 12);
        }
        let topology = builder.build().unwrap();
        let mut calibration = Calibration::new();
        for m in 0..modules {
            for k in 0..12 {
                let entry = SensorCalibration {
                    position: [f64::from(m) * 0.02 + f64::from(k % 4) * 0.004, f64::from(k / 4) * 0.004, 0.0],
                    normal: [0.0, 0.0, 1.0],
                    radius: 0.0015,
                    link: link(m).into(),
                };
                calibration.insert("layer", m * 12 + k + 1, entry).unwrap();
            }
        }
        SkinGeometry::build("labels", &[topology], &calibration, regions).unwrap()
    }

    #[test]
    fn the_virtual_bodys_pieces_are_labelled_with_their_links() {
        let geometry = crate::virtual_geometry("labelled", 2_000);
        let labels = piece_labels(&geometry);
        let mut texts: Vec<&str> = labels.iter().map(|l| l.text.as_str()).collect();
        texts.sort_unstable();
        let mut links: Vec<&str> = geometry.links.iter().map(String::as_str).collect();
        links.sort_unstable();
        assert_eq!(texts, links, "one label per body part");
        for label in &labels {
            let link = geometry.links.iter().position(|l| *l == label.text).unwrap() as u16;
            // The label's box holds every taxel of its link.
            for (sensor, &[x, y]) in geometry.map.positions.iter().enumerate() {
                if geometry.link_of[sensor] == link {
                    let [x0, y0, x1, y1] = label.bounds;
                    assert!((x0..=x1).contains(&x) && (y0..=y1).contains(&y), "{} at {x},{y}", label.text);
                }
            }
        }
    }

    #[test]
    fn a_links_many_pieces_get_one_label_unless_another_link_lies_among_them() {
        // Each module a piece; the map packs each link's pieces together, so one label each.
        for (modules, link) in [
            (12, (|m| if m < 6 { "torso" } else { "arm" }) as fn(u32) -> &'static str),
            (8, |m| if m % 2 == 0 { "torso" } else { "arm" }),
        ] {
            let geometry = modules_apart(modules, link, &[]);
            assert_eq!(geometry.map.piece_bounds.len(), modules as usize, "each module a piece");
            let labels = piece_labels(&geometry);
            let mut texts: Vec<&str> = labels.iter().map(|l| l.text.as_str()).collect();
            texts.sort_unstable();
            assert_eq!(texts, ["arm", "torso"], "{labels:?}");
        }
        // Pieces of one link with another link's piece between them keep a label each.
        let [a, b, c] = [[0.0, 0.0, 1.0, 1.0], [2.0, 0.0, 3.0, 1.0], [4.0, 0.0, 5.0, 1.0]];
        let mut groups = vec![
            Group { link: 0, bounds: a, pieces: vec![0] },
            Group { link: 1, bounds: b, pieces: vec![1] },
            Group { link: 0, bounds: c, pieces: vec![2] },
        ];
        merge_groups(&mut groups, &[a, b, c], &[Some(0), Some(1), Some(0)]);
        assert_eq!(groups.len(), 3, "a box around both 0s would cover the 1");
        let mut groups = vec![
            Group { link: 0, bounds: a, pieces: vec![0] },
            Group { link: 0, bounds: b, pieces: vec![1] },
            Group { link: 1, bounds: c, pieces: vec![2] },
        ];
        merge_groups(&mut groups, &[a, b, c], &[Some(0), Some(0), Some(1)]);
        assert_eq!(groups.len(), 2);
        assert_eq!(groups[0].bounds, [0.0, 0.0, 3.0, 1.0]);
        assert_eq!(groups[0].pieces, [0, 1]);
    }

    #[test]
    fn regions_holding_a_piece_whole_join_its_label_and_every_taxel_has_its_place() {
        let regions = [
            RegionSpec { name: "left_arm".into(), selectors: vec![Selector::Link("forearm".into())] },
            RegionSpec { name: "forearm".into(), selectors: vec![Selector::Link("forearm".into())] },
            RegionSpec { name: "first".into(), selectors: vec![Selector::Uids { layer: None, uids: vec![1, 2, 13] }] },
        ];
        let geometry = modules_apart(2, |m| if m == 0 { "forearm" } else { "hand" }, &regions);
        let labels = piece_labels(&geometry);
        let mut texts: Vec<&str> = labels.iter().map(|l| l.text.as_str()).collect();
        texts.sort_unstable();
        assert_eq!(texts, ["forearm · left_arm", "hand"], "a region named as the link is not repeated");

        let places = places(&geometry);
        assert_eq!(places.place_of.len(), 24);
        let place = |uid: u32| places.texts[places.place_of[uid as usize - 1] as usize].as_str();
        assert_eq!(place(1), "link forearm · regions left_arm, forearm, first");
        assert_eq!(place(3), "link forearm · regions left_arm, forearm");
        assert_eq!(place(13), "link hand · region first");
        assert_eq!(place(14), "link hand");
        assert_eq!(places.texts.len(), 4, "one text per distinct place");
    }
}
