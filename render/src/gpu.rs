//! The GPU device: adapter choice across wgpu's Vulkan and GL backends, and error capture.
//!
//! On a machine with a GPU the Vulkan driver of that GPU is used. On CPU-only machines Mesa
//! provides two software rasterisers: lavapipe behind Vulkan (package `mesa-vulkan-drivers`)
//! and llvmpipe behind EGL/OpenGL ES (packages `libegl1`, `libgl1-mesa-dri`), which most
//! machines already have. The automatic choice prefers a hardware adapter, then Vulkan, then GL.

use super::RenderError;
use std::sync::{Arc, Mutex};

/// Environment variable that forces a backend: `auto` (default), `vulkan` or `gl`.
pub const BACKEND_ENV: &str = "FUTAGO_GPU_BACKEND";

/// Which wgpu backend to render with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BackendChoice {
    /// A hardware adapter if there is one, else Vulkan (lavapipe), else GL (llvmpipe).
    Auto,
    Vulkan,
    Gl,
}

impl BackendChoice {
    /// Reads [`BACKEND_ENV`]; unset or empty means [`BackendChoice::Auto`].
    pub fn from_env() -> Result<BackendChoice, RenderError> {
        match std::env::var(BACKEND_ENV) {
            Err(_) => Ok(BackendChoice::Auto),
            Ok(v) => BackendChoice::parse(&v).ok_or_else(|| {
                RenderError::Config(format!(
                    "{BACKEND_ENV}={v:?}: expected one of \"auto\", \"vulkan\", \"gl\""
                ))
            }),
        }
    }

    /// Parses `auto`, `vulkan` or `gl` (case-insensitive).
    pub fn parse(s: &str) -> Option<BackendChoice> {
        match s.trim().to_ascii_lowercase().as_str() {
            "" | "auto" => Some(BackendChoice::Auto),
            "vulkan" | "vk" => Some(BackendChoice::Vulkan),
            "gl" | "gles" | "opengl" => Some(BackendChoice::Gl),
            _ => None,
        }
    }

    fn backends(self) -> wgpu::Backends {
        match self {
            BackendChoice::Auto => wgpu::Backends::VULKAN | wgpu::Backends::GL,
            BackendChoice::Vulkan => wgpu::Backends::VULKAN,
            BackendChoice::Gl => wgpu::Backends::GL,
        }
    }
}

/// Outcome of one buffer's map request.
type MapResult = Result<(), wgpu::BufferAsyncError>;

/// An open device with its queue and the errors it reported.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// The first uncaptured validation or out-of-memory error, if any.
    error: Arc<Mutex<Option<String>>>,
    /// Why the device was lost, if it was.
    lost: Arc<Mutex<Option<String>>>,
}

/// Ranks adapters: hardware first, then Vulkan before GL.
fn rank(info: &wgpu::AdapterInfo) -> (u8, u8) {
    let kind = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    let backend = match info.backend {
        wgpu::Backend::Vulkan => 0,
        _ => 1,
    };
    (kind, backend)
}

/// What to install for each backend, for the error when none is usable.
fn missing_help(choice: BackendChoice) -> String {
    let vk = "Vulkan: no adapter (on a CPU-only machine install Mesa's lavapipe, Debian package \
              `mesa-vulkan-drivers`)";
    let gl = "GL: no EGL/OpenGL ES adapter (install Mesa's EGL and llvmpipe, Debian packages \
              `libegl1` and `libgl1-mesa-dri`)";
    match choice {
        BackendChoice::Auto => format!("{vk}; {gl}"),
        BackendChoice::Vulkan => format!("{vk} ({BACKEND_ENV}=vulkan)"),
        BackendChoice::Gl => format!("{gl} ({BACKEND_ENV}=gl)"),
    }
}

impl Gpu {
    /// Opens the best adapter that `choice` allows, headless.
    pub fn open(choice: BackendChoice) -> Result<Gpu, RenderError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = choice.backends();
        // Validation layers would slow every call; wgpu-core still validates the API use.
        desc.flags = wgpu::InstanceFlags::empty();
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(choice.backends()));
        adapters.sort_by_key(|a| rank(&a.get_info()));
        let Some(adapter) = adapters.into_iter().next() else {
            return Err(RenderError::NoAdapter(missing_help(choice)));
        };
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("futago"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| {
            RenderError::Device(format!(
                "cannot open {} ({:?}): {e}",
                info.name, info.backend
            ))
        })?;
        let error = Arc::new(Mutex::new(None));
        let lost = Arc::new(Mutex::new(None));
        {
            let error = error.clone();
            device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                let mut slot = error.lock().unwrap_or_else(|p| p.into_inner());
                if slot.is_none() {
                    *slot = Some(e.to_string());
                }
            }));
        }
        {
            let lost = lost.clone();
            device.set_device_lost_callback(move |reason, message| {
                let mut slot = lost.lock().unwrap_or_else(|p| p.into_inner());
                *slot = Some(format!("{reason:?}: {message}"));
            });
        }
        Ok(Gpu {
            device,
            queue,
            info,
            limits,
            error,
            lost,
        })
    }

    /// One line naming the adapter, driver and backend.
    pub fn describe(&self) -> String {
        let i = &self.info;
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            i.name, i.backend, i.device_type, i.driver, i.driver_info
        )
    }

    /// Fails if the device was lost or reported an error since the last check.
    pub fn check(&self) -> Result<(), RenderError> {
        if let Some(why) = self.lost.lock().unwrap_or_else(|p| p.into_inner()).clone() {
            return Err(RenderError::DeviceLost(why));
        }
        if let Some(e) = self.error.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return Err(RenderError::Device(e));
        }
        Ok(())
    }

    /// Maps `buffers` for reading after submission `index`, waiting at most `timeout`.
    pub fn map_read(
        &self,
        buffers: &[&wgpu::Buffer],
        index: wgpu::SubmissionIndex,
        timeout: std::time::Duration,
    ) -> Result<(), RenderError> {
        let results: Arc<Mutex<Vec<Option<MapResult>>>> =
            Arc::new(Mutex::new(vec![None; buffers.len()]));
        for (i, b) in buffers.iter().enumerate() {
            let results = results.clone();
            b.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                results.lock().unwrap_or_else(|p| p.into_inner())[i] = Some(r);
            });
        }
        let polled = self.device.poll(wgpu::PollType::Wait {
            submission_index: Some(index),
            timeout: Some(timeout),
        });
        self.check()?;
        if let Err(e) = polled {
            return Err(match e {
                wgpu::PollError::Timeout => RenderError::DeviceLost(format!(
                    "the GPU did not finish a frame within {timeout:?}"
                )),
                other => RenderError::Device(other.to_string()),
            });
        }
        let results = results.lock().unwrap_or_else(|p| p.into_inner());
        for r in results.iter() {
            match r {
                Some(Ok(())) => {}
                Some(Err(e)) => return Err(RenderError::Device(format!("read-back: {e}"))),
                None => {
                    return Err(RenderError::Device(
                        "read-back did not complete after the GPU finished".into(),
                    ));
                }
            }
        }
        Ok(())
    }
}
