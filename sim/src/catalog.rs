//! Typical physical properties of the 40 AI2THOR categories (height of the centre, footprint
//! radius, visual size, instances placed when no position is known). Rough real-world values;
//! they drive object placement, visibility distance and how much of a view an object fills.

use super::types::CategoryProps;

const fn p(height: f32, radius: f32, size: f32, instances: u8) -> CategoryProps {
    CategoryProps {
        height,
        radius,
        size,
        instances,
    }
}

/// Properties of an AI2THOR category; a generic small object for unknown names.
pub fn props_of(name: &str) -> CategoryProps {
    match name {
        "AlarmClock" => p(0.8, 0.08, 0.3, 1),
        "ArmChair" => p(0.45, 0.45, 1.0, 1),
        "Bathtub" => p(0.3, 0.7, 1.5, 1),
        "BathtubBasin" => p(0.35, 0.6, 1.2, 1),
        "Book" => p(0.75, 0.12, 0.3, 2),
        "Bowl" => p(0.95, 0.1, 0.3, 1),
        "Box" => p(0.3, 0.25, 0.6, 1),
        "Cabinet" => p(0.5, 0.3, 0.8, 3),
        "Chair" => p(0.5, 0.3, 0.9, 2),
        "CoffeeMachine" => p(1.05, 0.15, 0.5, 1),
        "DeskLamp" => p(0.95, 0.12, 0.45, 1),
        "Drawer" => p(0.6, 0.25, 0.5, 2),
        "Faucet" => p(1.0, 0.08, 0.3, 1),
        "FloorLamp" => p(0.8, 0.2, 1.2, 1),
        "Fridge" => p(0.9, 0.4, 1.8, 1),
        "GarbageCan" => p(0.2, 0.18, 0.5, 1),
        "HousePlant" => p(0.5, 0.2, 0.7, 1),
        "Kettle" => p(1.0, 0.1, 0.35, 1),
        "Laptop" => p(0.7, 0.18, 0.45, 1),
        "LightSwitch" => p(1.3, 0.05, 0.3, 1),
        "Microwave" => p(1.1, 0.25, 0.6, 1),
        "Mug" => p(0.95, 0.06, 0.25, 1),
        "Painting" => p(1.6, 0.3, 0.8, 2),
        "Pan" => p(0.95, 0.15, 0.35, 1),
        "Pillow" => p(0.5, 0.2, 0.45, 2),
        "Plate" => p(0.95, 0.12, 0.3, 1),
        "Pot" => p(0.95, 0.15, 0.4, 1),
        "Shelf" => p(0.8, 0.3, 0.8, 2),
        "ShowerCurtain" => p(1.4, 0.4, 1.4, 1),
        "ShowerDoor" => p(1.2, 0.4, 1.5, 1),
        "SideTable" => p(0.35, 0.3, 0.7, 1),
        "Sink" => p(0.85, 0.3, 0.6, 1),
        "SinkBasin" => p(0.85, 0.25, 0.5, 1),
        "Sofa" => p(0.4, 0.7, 1.8, 1),
        "StoveBurner" => p(0.93, 0.12, 0.35, 4),
        "Television" => p(1.0, 0.35, 1.0, 1),
        "Toaster" => p(0.98, 0.1, 0.35, 1),
        "Toilet" => p(0.4, 0.3, 0.8, 1),
        "ToiletPaper" => p(0.7, 0.06, 0.25, 1),
        "TowelHolder" => p(1.1, 0.15, 0.35, 1),
        _ => p(0.8, 0.15, 0.4, 1),
    }
}
