//! Every model reader on arbitrary text: none may panic, hang or grow without bound. A URDF
//! that parses is then walked the way jobs walk it (a chain between every pair of links,
//! the whole tree below each link), which is where a cycle once looped forever.
#![no_main]
use libfuzzer_sys::fuzz_target;

use calibd::model::dh::DhFile;
use calibd::model::dh_tree::DhTreeFile;
use calibd::model::humanoid::MassTree;
use calibd::model::urdf::UrdfModel;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = DhFile::parse(text);
    let _ = calibd::model::srdf::disabled_collisions(text);
    if let Ok(tree) = DhTreeFile::parse(text, "fuzz") {
        for name in tree.chain_names() {
            let _ = tree.chain(name, "fuzz");
        }
    }
    if let Ok(urdf) = UrdfModel::parse(text) {
        let links: Vec<String> = urdf.robot.links.iter().map(|l| l.name.clone()).collect();
        for root in links.iter().take(8) {
            for tip in links.iter().take(8) {
                let _ = urdf.chain(root, tip);
            }
            let _ = MassTree::new(&urdf, root, &[]);
        }
    }
});
