//! The MPI group of a run launched by `mpirun` / `srun` (`--features mpi`, rsmpi over the
//! system's OpenMPI or MPICH).

use anyhow::{bail, Result};
use mpi::datatype::PartitionMut;
use mpi::topology::{Communicator, SimpleCommunicator};
use mpi::traits::*;
use mpi::Count;

use super::dist::Group;

/// The ranks of `MPI_COMM_WORLD`. MPI is finalised when the group is dropped.
pub struct MpiGroup {
    _universe: mpi::environment::Universe,
    world: SimpleCommunicator,
}

impl std::fmt::Debug for MpiGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MpiGroup(rank {} of {})", self.rank(), self.size())
    }
}

/// Whether this process was started by an MPI launcher (OpenMPI's `mpirun`, MPICH's Hydra,
/// Slurm's `srun` with PMI or PMIx): the environment variables they set.
pub fn launched_by_mpi() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "PMI_RANK"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

impl MpiGroup {
    /// Initialises MPI (once per process).
    pub fn init() -> Result<MpiGroup> {
        let Some(universe) = mpi::initialize() else {
            bail!("MPI could not be initialised (or was initialised before)");
        };
        let world = universe.world();
        Ok(MpiGroup {
            _universe: universe,
            world,
        })
    }

    /// Ends every rank of the job with `code` (MPI_Abort); never returns.
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
}

impl Group for MpiGroup {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        self.world.size() as usize
    }

    fn all_gather(&mut self, local: &[u8]) -> Result<Vec<Vec<u8>>> {
        let n = self.size();
        let Ok(mine) = Count::try_from(local.len()) else {
            bail!(
                "rank {}'s message of {} bytes exceeds MPI's count limit",
                self.rank(),
                local.len()
            );
        };
        let mut counts: Vec<Count> = vec![0; n];
        self.world.all_gather_into(&mine, &mut counts[..]);
        let mut displs: Vec<Count> = Vec::with_capacity(n);
        let mut total: i64 = 0;
        for &c in &counts {
            displs.push(total as Count);
            total += c as i64;
        }
        if total > Count::MAX as i64 {
            bail!("the ranks' messages add up to {total} bytes, more than MPI's count limit");
        }
        let mut buf = vec![0u8; total as usize];
        {
            let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
            self.world.all_gather_varcount_into(local, &mut part);
        }
        Ok(counts
            .iter()
            .zip(&displs)
            .map(|(&c, &d)| buf[d as usize..(d + c) as usize].to_vec())
            .collect())
    }

    fn barrier(&mut self) {
        self.world.barrier();
    }
}
