//! The 1 kHz path never allocates: `Collider::query` and `closest_surface_point`, in both modes,
//! on the liver and on a grid, counted by a global allocator wrapper.
//!
//! The counter is thread-local (a `const` initialiser, so reading it never allocates itself),
//! which keeps the test harness's own threads out of the count.

// In tests a panic is the failure report.
#![allow(clippy::unwrap_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use glam::{DQuat, DVec3};
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::liver;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_proto::{Pose, ToolShape};

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: the caller upholds `alloc`'s contract, passed on as is.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` above with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: as for `alloc` and `dealloc`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn queries_never_allocate() {
    // The counter sees this thread's allocations.
    let before = allocations();
    std::hint::black_box(vec![0u8; 16]);
    assert!(allocations() > before);

    let tools = [
        ToolShape::sphere(0.005).unwrap(),
        ToolShape::sphere(0.02).unwrap(),
        ToolShape::cone(0.5, 0.01).unwrap(),
    ];
    let meshes = [liver::haptic_mesh(), HapticMesh::grid(100, 0.1)];
    for mesh in meshes {
        let mut collider = Collider::new(mesh, CollisionMode::Continuous);
        for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
            collider.set_mode(mode);
            let before = allocations();
            let mut contacts = 0usize;
            for k in 0..2000 {
                let t = k as f64 * 0.01;
                let pose = Pose {
                    position_m: DVec3::new(0.08 * t.sin(), 0.07 * (0.7 * t).cos(), 0.05 * t.cos()),
                    orientation: DQuat::from_rotation_x(0.3 * t.sin()),
                };
                for tool in &tools {
                    contacts += usize::from(collider.query(tool, &pose).is_some());
                }
                std::hint::black_box(collider.closest_surface_point(pose.position_m, 0.05));
            }
            assert_eq!(allocations() - before, 0, "{mode:?} allocated");
            assert!(
                contacts > 100,
                "{mode:?}: the path must touch the surface ({contacts})"
            );
        }
    }
}
