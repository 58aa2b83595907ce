//! Hardware-in-the-loop tests of the SSD1306 128x32 status display on a mocked I2C bus
//! (embedded-hal-mock): the exact init command sequence, the addressing commands and the
//! 512 data bytes of a frame, redraw-only-on-change, an absent display, a bus fault in the
//! middle of a frame, and giving the bus back.
//!
//! On the wire (SSD1306 datasheet, I2C interface): every command is its own write, prefixed
//! with the control byte 0x00; frame data goes in writes of up to 16 bytes, prefixed with
//! the control byte 0x40. The frame bytes below come from this test's own renderer: the
//! SSD1306 page layout (byte = 8 vertical pixels, LSB on top, 4 pages of 128 columns).

use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::FONT_5X8;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};
use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource};
use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};
use jetpilot::hw::oled::{DisplayError, Oled, Status, StatusDisplay, layout};

const ADDR: u8 = 0x3C;
const CMD: u8 = 0x00;
const DATA: u8 = 0x40;

/// One command write: control byte 0x00, then the command and its arguments.
fn cmd(addr: u8, bytes: &[u8]) -> T {
    let mut v = vec![CMD];
    v.extend_from_slice(bytes);
    T::write(addr, v)
}

/// ssd1306 0.10's init for a 128x32 panel in buffered graphics mode, byte for byte.
fn init_commands(addr: u8) -> Vec<T> {
    vec![
        cmd(addr, &[0xAE]),       // display off
        cmd(addr, &[0xD5, 0x80]), // clock: oscillator 8, divide ratio 1
        cmd(addr, &[0xA8, 0x1F]), // multiplex ratio 32 (height - 1)
        cmd(addr, &[0xD3, 0x00]), // display offset 0
        cmd(addr, &[0x40]),       // start line 0
        cmd(addr, &[0x8D, 0x14]), // charge pump on
        cmd(addr, &[0x20, 0x00]), // horizontal addressing mode
        cmd(addr, &[0xDA, 0x02]), // COM pins: sequential, no left/right remap (128x32)
        cmd(addr, &[0xA1]),       // segment remap: column 127 is SEG0
        cmd(addr, &[0xC8]),       // COM scan direction reversed
        cmd(addr, &[0xD9, 0x21]), // precharge: phase 1 = 1, phase 2 = 2
        cmd(addr, &[0x81, 0x5F]), // contrast 0x5F
        cmd(addr, &[0xDB, 0x40]), // VCOMH deselect level "auto" (0b100)
        cmd(addr, &[0xA4]),       // display follows RAM
        cmd(addr, &[0xA6]),       // not inverted
        cmd(addr, &[0x2E]),       // scrolling off
        cmd(addr, &[0xAF]),       // display on
    ]
}

/// Full-frame addressing: columns 0..=127, pages 0..=3.
fn addressing(addr: u8) -> Vec<T> {
    vec![
        cmd(addr, &[0x21, 0x00, 0x7F]),
        cmd(addr, &[0x22, 0x00, 0x03]),
    ]
}

/// A frame as the bus sees it: addressing, then 32 writes of 0x40 + 16 bytes.
fn frame_writes(addr: u8, frame: &[u8; 512]) -> Vec<T> {
    let mut t = addressing(addr);
    for chunk in frame.chunks(16) {
        let mut v = vec![DATA];
        v.extend_from_slice(chunk);
        t.push(T::write(addr, v));
    }
    t
}

/// This test's own SSD1306 frame buffer.
struct Frame([u8; 512]);

impl OriginDimensions for Frame {
    fn size(&self) -> Size {
        Size::new(128, 32)
    }
}

impl DrawTarget for Frame {
    type Color = BinaryColor;
    type Error = core::convert::Infallible;
    fn draw_iter<I: IntoIterator<Item = Pixel<BinaryColor>>>(
        &mut self,
        pixels: I,
    ) -> Result<(), Self::Error> {
        for Pixel(p, c) in pixels {
            if (0..128).contains(&p.x) && (0..32).contains(&p.y) {
                let (x, y) = (p.x as usize, p.y as usize);
                let byte = &mut self.0[(y / 8) * 128 + x];
                let bit = 1u8 << (y % 8);
                if c.is_on() {
                    *byte |= bit;
                } else {
                    *byte &= !bit;
                }
            }
        }
        Ok(())
    }
}

/// The expected frame for `status`: the four layout lines in the 5x8 font, 8 pixels apart.
fn render(status: &Status) -> [u8; 512] {
    let mut f = Frame([0; 512]);
    let style = MonoTextStyle::new(&FONT_5X8, BinaryColor::On);
    for (row, line) in layout(status).iter().enumerate() {
        let _ = Text::with_baseline(line, Point::new(0, 8 * row as i32), style, Baseline::Top)
            .draw(&mut f);
    }
    f.0
}

fn status() -> Status {
    Status {
        mode: "auto".into(),
        fps: 29.8,
        speed: 0.25,
        steering: -0.1,
        interventions: 2,
        autonomy_percent: 98.0,
        ip: Some("192.168.1.23".into()),
    }
}

/// Init, including the blank frame that clears whatever the panel's RAM held.
fn init_then_blank(addr: u8) -> Vec<T> {
    let mut t = init_commands(addr);
    t.extend(frame_writes(addr, &[0; 512]));
    t
}

#[test]
fn init_sequence_is_literal() {
    // The whole init as a logic analyser would show it, without the helpers.
    let mut expected = vec![
        T::write(0x3C, vec![0x00, 0xAE]),
        T::write(0x3C, vec![0x00, 0xD5, 0x80]),
        T::write(0x3C, vec![0x00, 0xA8, 0x1F]),
        T::write(0x3C, vec![0x00, 0xD3, 0x00]),
        T::write(0x3C, vec![0x00, 0x40]),
        T::write(0x3C, vec![0x00, 0x8D, 0x14]),
        T::write(0x3C, vec![0x00, 0x20, 0x00]),
        T::write(0x3C, vec![0x00, 0xDA, 0x02]),
        T::write(0x3C, vec![0x00, 0xA1]),
        T::write(0x3C, vec![0x00, 0xC8]),
        T::write(0x3C, vec![0x00, 0xD9, 0x21]),
        T::write(0x3C, vec![0x00, 0x81, 0x5F]),
        T::write(0x3C, vec![0x00, 0xDB, 0x40]),
        T::write(0x3C, vec![0x00, 0xA4]),
        T::write(0x3C, vec![0x00, 0xA6]),
        T::write(0x3C, vec![0x00, 0x2E]),
        T::write(0x3C, vec![0x00, 0xAF]),
        T::write(0x3C, vec![0x00, 0x21, 0x00, 0x7F]),
        T::write(0x3C, vec![0x00, 0x22, 0x00, 0x03]),
    ];
    for _ in 0..32 {
        let mut v = vec![0x40];
        v.extend([0u8; 16]);
        expected.push(T::write(0x3C, v));
    }
    assert_eq!(
        expected,
        init_then_blank(0x3C),
        "the helpers agree with the literal"
    );
    let mut bus = Mock::new(&expected);
    let mut oled = Oled::new(bus.clone(), ADDR);
    oled.init().expect("init");
    drop(oled);
    bus.done();
}

#[test]
fn a_frame_is_addressing_plus_512_data_bytes() {
    let s = status();
    let frame = render(&s);
    assert!(frame.iter().any(|&b| b != 0), "the text lights some pixels");
    let writes = frame_writes(ADDR, &frame);
    assert_eq!(writes.len(), 2 + 32);
    let mut t = init_then_blank(ADDR);
    t.extend(writes);
    let mut bus = Mock::new(&t);
    let mut oled = Oled::new(bus.clone(), ADDR);
    oled.init().expect("init");
    oled.show(&s).expect("show");
    drop(oled);
    bus.done();
}

#[test]
fn only_a_visible_change_is_sent() {
    let a = status();
    // fps 29.81 renders as 29.8 like 29.8: nothing to send.
    let same_text = Status {
        fps: 29.81,
        ..a.clone()
    };
    let b = Status {
        interventions: 3,
        autonomy_percent: 97.0,
        ..a.clone()
    };
    let mut t = init_then_blank(ADDR);
    t.extend(frame_writes(ADDR, &render(&a)));
    t.extend(frame_writes(ADDR, &render(&b)));
    // clear(): a blank frame; the next show() of `b` is sent again.
    t.extend(frame_writes(ADDR, &[0; 512]));
    t.extend(frame_writes(ADDR, &render(&b)));
    let mut bus = Mock::new(&t);
    let mut oled = Oled::new(bus.clone(), ADDR);
    oled.init().expect("init");
    oled.show(&a).expect("a");
    oled.show(&a).expect("a again: no traffic");
    oled.show(&same_text).expect("same text: no traffic");
    oled.show(&b).expect("b");
    oled.clear().expect("clear");
    oled.show(&b).expect("b after clear");
    drop(oled);
    bus.done();
}

#[test]
fn an_absent_display_is_a_clear_error() {
    let expected = [T::write(ADDR, vec![CMD, 0xAE])
        .with_error(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address))];
    let bus = Mock::new(&expected);
    let mut oled = Oled::new(bus.clone(), ADDR);
    let e = oled.init().expect_err("nothing at 0x3C");
    assert!(
        matches!(e, DisplayError::NotFound { address: 0x3C, .. }),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(msg.starts_with("no SSD1306 at 0x3C on /dev/i2c-1"), "{msg}");
    assert!(msg.contains("no acknowledge"), "{msg}");
    // Not initialised: show() and clear() refuse without touching the bus.
    assert!(matches!(
        oled.show(&status()),
        Err(DisplayError::NotInitialised)
    ));
    assert!(matches!(oled.clear(), Err(DisplayError::NotInitialised)));
    // destroy() sends nothing to a display that never answered; `back` is `bus` (one mock).
    let mut back = oled.destroy().expect("the bus");
    back.done();
}

#[test]
fn other_address_and_bus_name_in_messages() {
    let expected = [T::write(0x3D, vec![CMD, 0xAE]).with_error(ErrorKind::Other)];
    let mut bus = Mock::new(&expected);
    let mut oled = Oled::new(bus.clone(), 0x3D).with_bus_name("/dev/i2c-8");
    assert_eq!(oled.address(), 0x3D);
    let msg = oled.init().expect_err("absent").to_string();
    assert!(msg.starts_with("no SSD1306 at 0x3D on /dev/i2c-8"), "{msg}");
    drop(oled);
    bus.done();
}

#[test]
fn a_bus_fault_mid_frame_is_reported_and_the_frame_resent() {
    let s = status();
    let frame = render(&s);
    let full = frame_writes(ADDR, &frame);
    let mut t = init_then_blank(ADDR);
    // addressing + 4 data writes, then the 5th fails: the rest is not sent.
    t.extend(full[..6].iter().cloned());
    t.push(full[6].clone().with_error(ErrorKind::Bus));
    // The next show() of the same status sends the whole frame again.
    t.extend(full.iter().cloned());
    let mut bus = Mock::new(&t);
    let mut oled = Oled::new(bus.clone(), ADDR);
    oled.init().expect("init");
    let e = oled.show(&s).expect_err("bus fault");
    assert!(
        matches!(e, DisplayError::Bus { address: 0x3C, .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("bus error"), "{e}");
    oled.show(&s).expect("resent");
    drop(oled);
    bus.done();
}

#[test]
fn destroy_turns_the_panel_off_and_gives_the_bus_back() {
    let mut t = init_then_blank(ADDR);
    t.push(cmd(ADDR, &[0xAE]));
    let bus = Mock::new(&t);
    let mut oled = Oled::new(bus.clone(), ADDR);
    oled.init().expect("init");
    let mut back = oled.destroy().expect("the bus");
    back.done(); // the same mock as `bus`: every expected write happened
}

#[test]
fn the_display_is_send_behind_the_trait() {
    fn takes(_: Box<dyn StatusDisplay>) {}
    let mut bus = Mock::new(&[]);
    takes(Box::new(Oled::new(bus.clone(), ADDR)));
    bus.done();
}
