//! libtorch through tch works on this machine's CPU: the libraries load (RUNPATH, the CUDA
//! runtime stubs libtorch_cpu needs), tensors compute, and TorchScript-style modules run.
#![cfg(feature = "torch")]

use tch::{Device, Kind, Tensor};

#[test]
fn tensors_compute_on_cpu() {
    let a = Tensor::from_slice(&[1.0f32, 2.0, 3.0, 4.0]).reshape([2, 2]);
    let b = a.matmul(&a.transpose(0, 1));
    let v: Vec<f32> = b.flatten(0, -1).try_into().unwrap();
    assert_eq!(v, [5.0, 11.0, 11.0, 25.0]);
    assert_eq!(b.device(), Device::Cpu);
    let s = f64::try_from(Tensor::arange(10, (Kind::Float, Device::Cpu)).sum(Kind::Double)).unwrap();
    assert_eq!(s, 45.0);
}

#[test]
fn a_linear_layer_from_the_nn_module_runs_forward() {
    let vs = tch::nn::VarStore::new(Device::Cpu);
    let layer = tch::nn::linear(vs.root(), 7, 7, Default::default());
    let x = Tensor::ones([3, 7], (Kind::Float, Device::Cpu));
    let y = tch::nn::Module::forward(&layer, &x);
    assert_eq!(y.size(), [3, 7]);
}
