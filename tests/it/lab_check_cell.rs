//! `lab check` compares what the devices report with the cell: the QTM row with the cell's
//! markers (through the lab file's label map), the joints row with the cell's envelope
//! (the TALOS twin's QTM and joint-interface mock servers, over their real protocols).

use std::time::Duration;

use calibd::lab::{CellLink, DeviceReport, DeviceStatus, Lab};
use calibd::model::humanoid::MarkerDef;

async fn check(cell: &calibd::lab::MocapCellLink) -> Vec<DeviceReport> {
    let lab = Lab::connect(vec![CellLink::Mocap(cell.clone())]).expect("lab");
    let r = lab.check(Duration::from_secs(10)).await;
    eprintln!("{}", calibd::lab::devices::table(&r));
    lab.stop().await;
    r
}

fn row<'a>(r: &'a [DeviceReport], device: &str) -> &'a DeviceStatus {
    &r.iter()
        .find(|x| x.device == device)
        .unwrap_or_else(|| panic!("no row {device}"))
        .status
}

fn error(s: &DeviceStatus) -> String {
    match s {
        DeviceStatus::Failed { error, .. } => error.clone(),
        other => panic!("expected a failed row, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_qtm_and_joints_rows_compare_the_devices_with_the_cell() {
    let (cell, mocks) = calibd::sim::mocap::start_at(
        7,
        &calibd::sim::SimMocapOptions::default(),
        "127.0.0.1:0",
        "127.0.0.1:0",
    )
    .await
    .expect("talos twin");
    let n = cell.markers.len();
    assert!(n >= 3, "{n} markers");

    // As served: every marker labelled, the envelope inside the interface's limits.
    let r = check(&cell).await;
    match row(&r, "talos.qtm") {
        DeviceStatus::Ok { identity, .. } => assert!(
            identity
                .summary
                .contains(&format!("all {n} cell markers labelled")),
            "{identity:?}"
        ),
        other => panic!("{other:?}"),
    }
    assert!(matches!(row(&r, "talos.joints"), DeviceStatus::Ok { .. }));

    // The cell expects two markers the stream does not label, and its envelope reaches
    // 10 deg beyond the interface's lower limit of its third joint.
    let mut bad = cell.clone();
    let first = bad.markers[0].name.clone();
    bad.markers[0].name = "ghost_a".into();
    bad.markers.push(MarkerDef {
        name: "ghost_b".into(),
        ..bad.markers[1].clone()
    });
    bad.limits[2][0] -= 10f64.to_radians();
    let joint = bad.joint_names[2].clone();
    let r = check(&bad).await;
    let e = error(row(&r, "talos.qtm"));
    assert!(
        e.contains(&format!(
            "2 of the cell's {} markers are not in the stream: ghost_a, ghost_b",
            n + 1
        )),
        "{e}"
    );
    assert!(e.ends_with("not in the stream: ghost_a, ghost_b"), "{e}");
    let e = error(row(&r, "talos.joints"));
    assert!(
        e.contains("beyond the interface's limits") && e.contains(&format!("{joint}: envelope [")),
        "{e}"
    );
    // Only that joint: the others are the interface's own limits.
    assert_eq!(e.matches(": envelope [").count(), 1, "{e}");
    let table = calibd::lab::devices::table(&r);
    assert_eq!(table.matches("FAILED").count(), 2, "{table}");

    // The lab file's label map names the stream's label for the renamed marker: found again.
    let mut mapped = bad.clone();
    mapped.markers.pop();
    mapped.limits = cell.limits.clone();
    mapped.labels.insert(first.clone(), "ghost_a".into());
    let r = check(&mapped).await;
    assert!(
        matches!(row(&r, "talos.qtm"), DeviceStatus::Ok { .. }),
        "{:?}",
        row(&r, "talos.qtm")
    );
    for m in mocks {
        m.stop().await;
    }
}
